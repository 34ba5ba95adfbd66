"""What the UR10e does with bad actions and how it counts them, through the robot's Python API (sim backend).

Every refusal stops the arm, is counted in ``safety_counters["rejected_actions"]`` and does not feed the
watchdog; every value the driver changes (a clipped gripper command) is counted; counters survive disconnect.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("mujoco")

from lerobot_focal.robots.ur10e import UR10e, UR10eConfig  # noqa: E402
from lerobot_focal.robots.ur10e.safety import SafetyConfig  # noqa: E402


@pytest.fixture
def robot(tmp_path):
    r = UR10e(UR10eConfig(backend="sim", calibration_dir=tmp_path, safety=SafetyConfig(watchdog_timeout_s=0.3)))
    r.connect()
    yield r
    if r.is_connected:
        r.disconnect()


def _move(robot: UR10e, steps: int = 8) -> None:
    for _ in range(steps):
        robot.send_action({"ee_x.vel": 0.2})
        time.sleep(1 / robot.config.control_hz)


def _speed(robot: UR10e) -> float:
    return float(np.abs(robot.backend.joint_velocities()).max())


def _wait_until(predicate, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.01)
    return predicate()


def test_watchdog_stops_are_still_counted_after_disconnect(robot):
    for trip in range(1, 7):
        robot.send_action({"ee_x.vel": 0.0})
        assert _wait_until(lambda t=trip: robot.safety_counters["watchdog_stops"] == t), robot.safety_counters
    robot.disconnect()
    assert robot.safety_counters["watchdog_stops"] == 6
    robot.connect()  # a new connection adds to the same count
    robot.send_action({"ee_x.vel": 0.0})
    assert _wait_until(lambda: robot.safety_counters["watchdog_stops"] == 7)


@pytest.mark.parametrize(
    ("action", "message"),
    [
        ({}, "none of the robot's keys"),
        ({"x": 0.1, "speed": 1.0}, "none of the robot's keys"),
        ({"ee_x.vel": 0.1, "ee_x.pos": -0.6}, "mixes absolute"),
        ({"ee_x.pos": -0.6, "ee_y.pos": 0.0}, "missing"),
        ({"ee_x.vel": "0.1"}, "must be a number, got str"),
        ({"ee_x.vel": np.array([0.1, 0.2])}, r"must be one number, got an array of shape \(2,\)"),
        ({"ee_x.vel": float("nan")}, "non-finite"),
    ],
    ids=["empty", "unknown-keys", "mixed", "missing", "string", "array", "nan"],
)
def test_refused_actions_stop_the_arm_are_counted_and_do_not_feed_the_watchdog(robot, action, message):
    _move(robot)
    assert _speed(robot) > 0.01  # moving
    before = robot.safety_counters
    with pytest.raises(ValueError, match=message):
        robot.send_action(action)
    after = robot.safety_counters
    assert after["rejected_actions"] == before["rejected_actions"] + 1
    assert _wait_until(lambda: _speed(robot) < 1e-3, 2.0), _speed(robot)  # stopped, not coasting to the target
    # A stream of refused actions is not a stream of commands: the watchdog still trips.
    for _ in range(int(0.6 * robot.config.control_hz)):
        with pytest.raises(ValueError):
            robot.send_action(action)
        time.sleep(1 / robot.config.control_hz)
    assert robot.safety_counters["watchdog_stops"] == before["watchdog_stops"] + 1


def test_gripper_commands_outside_0_1_are_clipped_and_counted(robot):
    assert robot.send_action({"ee_x.vel": 0.0, "gripper.pos": 50})["gripper.pos"] == 1.0
    assert robot.send_action({"ee_x.vel": 0.0, "gripper.pos": -3})["gripper.pos"] == 0.0
    assert robot.send_action({"ee_x.vel": 0.0, "gripper.pos": 0.5})["gripper.pos"] == 0.5
    assert robot.safety_counters["gripper_clips"] == 2
    assert robot.safety_counters["rejected_actions"] == 0


def test_numpy_and_one_element_values_are_numbers(robot):
    sent = robot.send_action({"ee_x.vel": np.float32(0.05), "ee_y.vel": np.array(0.0), "ee_z.vel": np.array([0.0])})
    assert sent["ee_x.vel"] == pytest.approx(0.05, abs=1e-6)
    assert robot.safety_counters["rejected_actions"] == 0

