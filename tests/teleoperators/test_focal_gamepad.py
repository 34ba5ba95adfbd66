"""focal_gamepad through its real device path: pygame reading an SDL virtual joystick laid out like an F710.

The only thing replaced is the physical pad (see virtual_joystick.py); pygame, SDL's joystick layer and event
queue, and the teleoperator's hot-unplug handling all run for real.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("pygame")
sys.path.insert(0, str(Path(__file__).parent))

from lerobot.teleoperators.config import TeleoperatorConfig  # noqa: E402
from lerobot.teleoperators.utils import TeleopEvents, make_teleoperator_from_config  # noqa: E402
from lerobot.utils.errors import DeviceNotConnectedError  # noqa: E402
from virtual_joystick import F710, F710Button, VirtualJoystick  # noqa: E402

from lerobot_focal.config_errors import ConfigError
from lerobot_focal.teleoperators import FocalGamepad, FocalGamepadConfig  # noqa: E402
from lerobot_focal.teleoperators.focal_gamepad import (  # noqa: E402
    VELOCITY_NAMES,
    GamepadDisconnectedError,
)
from lerobot_focal.teleoperators.focal_gamepad.focal_gamepad import apply_deadzone  # noqa: E402

T, R = 0.15, 0.9  # default max linear (m/s) / angular (rad/s) speed


@pytest.fixture
def pad():
    with VirtualJoystick() as joystick:
        yield joystick


def _teleop(tmp_path, **kw) -> FocalGamepad:
    teleop = FocalGamepad(FocalGamepadConfig(calibration_dir=tmp_path, **kw))
    teleop.connect()
    return teleop


@pytest.fixture
def teleop(pad, tmp_path):
    teleop = _teleop(tmp_path)
    yield teleop
    teleop.disconnect()


def _deltas(action: dict) -> list[float]:
    return [action[name] for name in VELOCITY_NAMES]


def test_registered_and_built_by_lerobot_factory(tmp_path):
    config = TeleoperatorConfig.get_choice_class("focal_gamepad")(calibration_dir=tmp_path)
    teleop = make_teleoperator_from_config(config)
    assert isinstance(teleop, FocalGamepad)
    assert list(teleop.action_features) == [*VELOCITY_NAMES, "gripper.pos"]
    assert all(t is float for t in teleop.action_features.values())


def test_no_motion_without_deadman(pad, teleop):
    pad.set_axis(F710.LEFT_Y, -1.0)
    pad.set_axis(F710.RIGHT_X, 1.0)
    pad.set_axis(F710.RT, 1.0)
    action = teleop.get_action()
    assert _deltas(action) == [0.0] * 6
    assert action["gripper.pos"] == 1.0
    assert teleop.get_teleop_events()[TeleopEvents.IS_INTERVENTION] is False


@pytest.mark.parametrize(
    ("axis", "value", "expected"),
    [
        (F710.LEFT_Y, -1.0, {"ee_x.vel": T}),  # stick forward: +x
        (F710.LEFT_Y, 1.0, {"ee_x.vel": -T}),
        (F710.LEFT_X, -1.0, {"ee_y.vel": T}),  # stick left: +y
        (F710.RIGHT_Y, -1.0, {"ee_z.vel": T}),  # right stick up: +z
        (F710.RIGHT_X, -1.0, {"ee_yaw.vel": R}),  # right stick left: +yaw
    ],
)
def test_axis_to_delta_mapping_and_sign(pad, teleop, axis, value, expected):
    pad.set_button(F710Button.LB, True)
    pad.set_axis(axis, value)
    action = teleop.get_action()
    full = dict.fromkeys(VELOCITY_NAMES, 0.0) | {k: v * 0.5 for k, v in expected.items()}  # speed level 1 = 0.5
    assert _deltas(action) == pytest.approx([full[n] for n in VELOCITY_NAMES], abs=1e-4)
    assert teleop.get_teleop_events()[TeleopEvents.IS_INTERVENTION] is True


def test_rotation_mode_turns_left_stick_into_roll_pitch(pad, teleop):
    pad.set_button(F710Button.LB, True)
    pad.set_button(F710Button.RB, True)
    pad.set_axis(F710.LEFT_X, 1.0)
    pad.set_axis(F710.LEFT_Y, -1.0)
    action = teleop.get_action()
    assert action["ee_x.vel"] == 0.0 and action["ee_y.vel"] == 0.0
    assert action["ee_roll.vel"] == pytest.approx(R * 0.5, abs=1e-4)
    assert action["ee_pitch.vel"] == pytest.approx(R * 0.5, abs=1e-4)


def test_deadzone_and_release_give_exact_zero(pad, teleop):
    pad.set_button(F710Button.LB, True)
    pad.set_axis(F710.LEFT_Y, -0.1)  # inside the default 0.12 deadzone: stick drift
    assert _deltas(teleop.get_action()) == [0.0] * 6
    pad.set_axis(F710.LEFT_Y, -0.56)
    assert teleop.get_action()["ee_x.vel"] == pytest.approx(apply_deadzone(0.56, 0.12) * T * 0.5, abs=1e-4)
    pad.set_axis(F710.LEFT_Y, -1.0)
    assert teleop.get_action()["ee_x.vel"] > 0
    pad.set_button(F710Button.LB, False)  # deadman released mid-motion, stick still pushed
    assert _deltas(teleop.get_action()) == [0.0] * 6


def test_deadzone_is_continuous():
    assert apply_deadzone(0.12, 0.12) == 0.0
    assert 0.0 < apply_deadzone(0.13, 0.12) < 0.02
    assert apply_deadzone(-1.0, 0.12) == -1.0


def test_dpad_changes_speed_level(pad, teleop):
    pad.set_button(F710Button.LB, True)
    pad.set_axis(F710.LEFT_Y, -1.0)
    assert teleop.get_action()["ee_x.vel"] == pytest.approx(T * 0.5, abs=1e-4)
    pad.set_hat(0, (0, 1))
    pad.pump()
    pad.set_hat(0, (0, 0))
    assert teleop.get_action()["ee_x.vel"] == pytest.approx(T * 1.0, abs=1e-4)
    pad.set_hat(0, (0, 1))  # already at the top level: stays
    assert teleop.get_action()["ee_x.vel"] == pytest.approx(T * 1.0, abs=1e-4)
    for _ in range(3):
        pad.set_hat(0, (0, 0))
        pad.pump()
        pad.set_hat(0, (0, -1))
        pad.pump()
    assert teleop.get_action()["ee_x.vel"] == pytest.approx(T * 0.25, abs=1e-4)
    assert teleop.speed_level == 0


def test_gripper_triggers_toggle_and_deadman(pad, teleop):
    pad.set_axis(F710.RT, 1.0)
    assert teleop.get_action()["gripper.pos"] == 1.0  # deadman released: gripper holds
    pad.set_button(F710Button.LB, True)
    values = [teleop.get_action()["gripper.pos"] for _ in range(3)]
    assert values == pytest.approx([0.95, 0.90, 0.85])
    pad.set_axis(F710.RT, -1.0)
    pad.set_axis(F710.LT, 1.0)
    assert teleop.get_action()["gripper.pos"] == pytest.approx(0.90)
    pad.set_axis(F710.LT, 0.0)  # F710 triggers read mid-range until first touched: must not count as pressed
    assert teleop.get_action()["gripper.pos"] == pytest.approx(0.90)
    pad.press(F710Button.A)
    assert teleop.get_action()["gripper.pos"] == 0.0
    pad.press(F710Button.A)
    assert teleop.get_action()["gripper.pos"] == 1.0


def test_episode_events_latch_until_read(pad, teleop):
    pad.press(F710Button.Y)
    teleop.get_action()  # the control loop drains the queue first: the press must not be lost
    events = teleop.get_teleop_events()
    assert events[TeleopEvents.SUCCESS] and events[TeleopEvents.TERMINATE_EPISODE]
    assert not teleop.get_teleop_events()[TeleopEvents.TERMINATE_EPISODE]
    pad.press(F710Button.X)
    events = teleop.get_teleop_events()
    assert events[TeleopEvents.RERECORD_EPISODE] and not events[TeleopEvents.SUCCESS]
    pad.press(F710Button.B)
    events = teleop.get_teleop_events()
    assert events[TeleopEvents.TERMINATE_EPISODE] and not events[TeleopEvents.SUCCESS]


def test_unplugged_pad_raises_clear_error(pad, teleop):
    pad.set_button(F710Button.LB, True)
    pad.set_axis(F710.LEFT_Y, -1.0)
    assert teleop.get_action()["ee_x.vel"] > 0
    pad.detach()
    with pytest.raises(GamepadDisconnectedError, match="disconnected.*reconnect"):
        teleop.get_action()
    assert not teleop.is_connected
    with pytest.raises(DeviceNotConnectedError):
        teleop.get_action()


def test_unplugged_pad_in_zero_mode_stops_motion_and_recovers(tmp_path):
    pad = VirtualJoystick().attach()
    teleop = _teleop(tmp_path, on_disconnect="zero")
    try:
        pad.set_button(F710Button.LB, True)
        pad.set_axis(F710.LEFT_Y, -1.0)
        assert teleop.get_action()["ee_x.vel"] > 0
        pad.detach()
        action = teleop.get_action()
        assert _deltas(action) == [0.0] * 6 and action["gripper.pos"] == 1.0
        pad.attach()  # plugged back in, at rest: no motion until the deadman is pressed again
        assert _deltas(teleop.get_action()) == [0.0] * 6
        pad.set_button(F710Button.LB, True)
        pad.set_axis(F710.LEFT_X, 1.0)
        assert teleop.get_action()["ee_y.vel"] < 0
    finally:
        teleop.disconnect()
        pad.detach()


def test_missing_pad_fails_at_connect_listing_what_sdl_sees(pad, tmp_path):
    with pytest.raises(DeviceNotConnectedError, match=r"F710.*Virtual Controller"):
        FocalGamepad(FocalGamepadConfig(calibration_dir=tmp_path, name_contains="F710")).connect()


def test_custom_mapping_and_signs(pad, tmp_path):
    teleop = _teleop(tmp_path, signs=[-1.0, 1.0, 1.0, 1.0, 1.0, 1.0], speed_levels=[1.0], initial_speed_level=0)
    teleop.config.mapping.deadman_button = F710Button.RB
    teleop.config.mapping.rotation_button = F710Button.BACK
    try:
        pad.set_button(F710Button.LB, True)
        pad.set_axis(F710.LEFT_Y, -1.0)
        assert teleop.get_action()["ee_x.vel"] == 0.0  # LB is no longer the deadman
        pad.set_button(F710Button.RB, True)
        assert teleop.get_action()["ee_x.vel"] == pytest.approx(-T, abs=1e-4)
    finally:
        teleop.disconnect()


def test_bad_config_is_refused():
    with pytest.raises(ConfigError, match="initial_speed_level"):
        FocalGamepadConfig(speed_levels=[0.5], initial_speed_level=2)
    with pytest.raises(ConfigError, match="on_disconnect"):
        FocalGamepadConfig(on_disconnect="ignore")
