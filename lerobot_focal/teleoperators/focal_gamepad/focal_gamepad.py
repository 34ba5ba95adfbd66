"""6-DoF end-effector teleoperation from a gamepad (``--teleop.type=focal_gamepad``).

LeRobot's own ``gamepad`` teleoperator gives xyz + gripper only; the UR-10e demos need orientation too, and a
deadman so that a dropped or bumped pad never moves the arm.

Action (what :meth:`FocalGamepad.get_action` returns; the UR-10e robot, ``action_mode=velocity``, integrates the
velocities over one control period into end-effector targets). The names end in ``.vel`` / ``.pos`` because
``lerobot-rollout`` only routes robot features with those suffixes to a policy:

===============  ======================================================================================
``ee_x.vel``     TCP velocity along the robot base X axis, m/s (left stick forward = +X)
``ee_y.vel``     ... base Y, m/s (left stick pushed left = +Y)
``ee_z.vel``     ... base Z, m/s (right stick pushed up = +Z)
``ee_roll.vel``  angular velocity about base X, rad/s (rotation mode, left stick right = +)
``ee_pitch.vel`` angular velocity about base Y, rad/s (rotation mode, left stick forward = +)
``ee_yaw.vel``   angular velocity about base Z, rad/s (right stick left = +)
``gripper.pos``  commanded gripper opening as a fraction: 1 = fully open, 0 = fully closed (absolute)
===============  ======================================================================================

The six velocities are exactly zero unless the deadman button is held, and the gripper command does not change
while it is released. The button/axis map is in :mod:`.config_focal_gamepad`.

pygame is imported at :meth:`connect`, not at import time, because every ``lerobot-*`` command imports this
plugin and most of them never touch a gamepad.
"""

from __future__ import annotations

import logging
import os
from typing import Any

from lerobot.lerobot_types import RobotAction
from lerobot.teleoperators.teleoperator import Teleoperator
from lerobot.teleoperators.utils import TeleopEvents
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected
from lerobot.utils.errors import DeviceNotConnectedError
from lerobot.utils.import_utils import require_package

from .config_focal_gamepad import FocalGamepadConfig

logger = logging.getLogger(__name__)

VELOCITY_NAMES = ("ee_x.vel", "ee_y.vel", "ee_z.vel", "ee_roll.vel", "ee_pitch.vel", "ee_yaw.vel")
GRIPPER_NAME = "gripper.pos"

_HAT_UP, _HAT_DOWN = 1, -1


class GamepadDisconnectedError(DeviceNotConnectedError):
    """The gamepad vanished (unplugged, receiver out of range, batteries flat)."""


def apply_deadzone(value: float, deadzone: float) -> float:
    """Zero inside the deadzone, rescaled outside it so the output starts at 0 at the edge (no jump)."""
    magnitude = abs(value)
    if magnitude <= deadzone:
        return 0.0
    return (min(magnitude, 1.0) - deadzone) / (1.0 - deadzone) * (1.0 if value > 0 else -1.0)


def sticks_to_deltas(
    left_x: float, left_y: float, right_x: float, right_y: float, rotation_mode: bool
) -> tuple[float, float, float, float, float, float]:
    """Map stick deflections (SDL convention: right and down are +) to unit (dx, dy, dz, droll, dpitch, dyaw)."""
    dz, dyaw = -right_y, -right_x
    if rotation_mode:
        return 0.0, 0.0, dz, left_x, -left_y, dyaw
    return -left_y, -left_x, dz, 0.0, 0.0, dyaw


class FocalGamepad(Teleoperator):
    """Gamepad teleoperator for end-effector deltas, with deadman, speed levels and gripper command."""

    config_class = FocalGamepadConfig
    name = "focal_gamepad"

    def __init__(self, config: FocalGamepadConfig):
        super().__init__(config)
        self.config = config
        self._pygame = None
        self._joystick = None
        self._joystick_name: str | None = None
        self._instance_id: int | None = None
        self._lost = False
        self.speed_level = config.initial_speed_level
        self.gripper = float(config.initial_gripper)
        self._pending_events: set[TeleopEvents] = set()

    # ------------------------------------------------------------------ LeRobot interface
    @property
    def action_features(self) -> dict[str, type]:
        return {**{name: float for name in VELOCITY_NAMES}, GRIPPER_NAME: float}

    @property
    def feedback_features(self) -> dict:
        return {}

    @property
    def is_connected(self) -> bool:
        return self._joystick is not None

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        """Sticks are self-centring and the deadzone absorbs drift: nothing to calibrate."""

    def configure(self) -> None:
        """Nothing to configure on the device."""

    def send_feedback(self, feedback: dict[str, Any]) -> None:
        """No feedback channel (the F710 has rumble, but no one needs it yet)."""

    @property
    def speed_factor(self) -> float:
        return self.config.speed_levels[self.speed_level]

    @check_if_already_connected
    def connect(self, calibrate: bool = True) -> None:
        require_package("pygame", extra="gamepad")
        # Joystick events need SDL's event loop, which pygame ties to its video subsystem; a headless robot PC
        # has no display, so fall back to SDL's dummy video driver (no window is ever opened).
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
        # Keep receiving stick input when another window (rerun viewer, terminal) has focus.
        os.environ.setdefault("SDL_JOYSTICK_ALLOW_BACKGROUND_EVENTS", "1")
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        import pygame

        self._pygame = pygame
        pygame.init()  # idempotent; never pygame.quit() here: that would tear down other pygame users
        if not pygame.display.get_init():
            os.environ["SDL_VIDEODRIVER"] = "dummy"
            pygame.display.init()
        if not pygame.joystick.get_init():
            pygame.joystick.init()
        pygame.event.pump()
        joystick = self._find_joystick()
        if joystick is None:
            raise DeviceNotConnectedError(self._not_found_message())
        self._adopt(joystick)
        pygame.event.clear([pygame.JOYBUTTONDOWN, pygame.JOYHATMOTION])  # presses before connect don't count
        logger.info("focal_gamepad: using %r (instance %s)", self._joystick_name, self._instance_id)

    def disconnect(self) -> None:
        if self._joystick is not None:
            try:
                self._joystick.quit()
            except Exception:  # noqa: BLE001  # nosec B110 - the device may already be gone; closing is best-effort
                pass
        self._joystick = None
        self._lost = False

    @check_if_not_connected
    def get_action(self) -> RobotAction:
        self._poll()
        zeros = dict.fromkeys(VELOCITY_NAMES, 0.0)
        if self._lost:
            return {**zeros, GRIPPER_NAME: self.gripper}
        js, m = self._joystick, self.config.mapping
        if not js.get_button(m.deadman_button):
            return {**zeros, GRIPPER_NAME: self.gripper}

        dz = self.config.deadzone
        unit = sticks_to_deltas(
            apply_deadzone(js.get_axis(m.left_x_axis), dz),
            apply_deadzone(js.get_axis(m.left_y_axis), dz),
            apply_deadzone(js.get_axis(m.right_x_axis), dz),
            apply_deadzone(js.get_axis(m.right_y_axis), dz),
            rotation_mode=bool(js.get_button(m.rotation_button)),
        )
        steps = [self.config.max_linear_speed] * 3 + [self.config.max_angular_speed] * 3
        action = {
            name: float(u * step * sign * self.speed_factor) + 0.0  # + 0.0 turns -0.0 into 0.0
            for name, u, step, sign in zip(VELOCITY_NAMES, unit, steps, self.config.signs, strict=True)
        }

        if self._trigger(m.right_trigger_axis):
            self.gripper -= self.config.gripper_step
        if self._trigger(m.left_trigger_axis):
            self.gripper += self.config.gripper_step
        self.gripper = min(max(self.gripper, 0.0), 1.0)
        action[GRIPPER_NAME] = self.gripper
        return action

    def get_teleop_events(self) -> dict[TeleopEvents, bool]:
        """LeRobot's teleop events; episode events latch until read here. Intervention = deadman held."""
        if not self.is_connected:
            return {e: False for e in TeleopEvents if e != TeleopEvents.FAILURE}
        self._poll()
        events, self._pending_events = self._pending_events, set()
        intervening = not self._lost and bool(self._joystick.get_button(self.config.mapping.deadman_button))
        return {
            TeleopEvents.IS_INTERVENTION: intervening,
            TeleopEvents.TERMINATE_EPISODE: bool(events),
            TeleopEvents.SUCCESS: TeleopEvents.SUCCESS in events,
            TeleopEvents.RERECORD_EPISODE: TeleopEvents.RERECORD_EPISODE in events,
        }

    # ------------------------------------------------------------------ device plumbing
    def _find_joystick(self):
        pygame = self._pygame
        count = pygame.joystick.get_count()
        if self.config.name_contains is None:
            if self.config.joystick_index < count:
                return pygame.joystick.Joystick(self.config.joystick_index)
            return None
        wanted = self.config.name_contains.lower()
        for index in range(count):
            joystick = pygame.joystick.Joystick(index)
            if wanted in joystick.get_name().lower():
                return joystick
        return None

    def _adopt(self, joystick) -> None:
        joystick.init()
        self._joystick = joystick
        self._joystick_name = joystick.get_name()
        self._instance_id = joystick.get_instance_id()
        self._lost = False

    def _not_found_message(self) -> str:
        pygame = self._pygame
        names = [pygame.joystick.Joystick(i).get_name() for i in range(pygame.joystick.get_count())]
        which = (
            f"a joystick whose name contains {self.config.name_contains!r}"
            if self.config.name_contains is not None
            else f"joystick index {self.config.joystick_index}"
        )
        return (
            f"focal_gamepad: no {which}; SDL sees {names or 'no joysticks at all'}. Plug in the F710's USB "
            "receiver, switch the pad to XInput ('X' on its back), press a button to wake it, or set "
            "--teleop.joystick_index / --teleop.name_contains."
        )

    def _trigger(self, axis: int) -> bool:
        return (self._joystick.get_axis(axis) + 1.0) / 2.0 > self.config.trigger_threshold

    def _poll(self) -> None:
        """Drain joystick events: latch button/D-pad presses (so a press shorter than a control step still
        counts) and notice the pad being unplugged or plugged back in."""
        pygame = self._pygame
        m = self.config.mapping
        joy_events = [
            pygame.JOYAXISMOTION, pygame.JOYBALLMOTION, pygame.JOYBUTTONDOWN, pygame.JOYBUTTONUP,
            pygame.JOYHATMOTION, pygame.JOYDEVICEADDED, pygame.JOYDEVICEREMOVED,
        ]  # fmt: skip
        for event in pygame.event.get(joy_events):
            if event.type == pygame.JOYDEVICEREMOVED and event.instance_id == self._instance_id:
                self._on_lost()
            elif event.type == pygame.JOYDEVICEADDED and self._lost:
                self._try_reattach()
            elif self._lost or getattr(event, "instance_id", None) != self._instance_id:
                continue
            elif event.type == pygame.JOYHATMOTION and event.hat == m.speed_hat:
                step = {_HAT_UP: 1, _HAT_DOWN: -1}.get(event.value[1], 0)
                self.speed_level = min(max(self.speed_level + step, 0), len(self.config.speed_levels) - 1)
            elif event.type == pygame.JOYBUTTONDOWN:
                self._on_button(event.button)
        # Belt and braces: if someone else drained the queue, the device count still tells us it is gone.
        if not self._lost and pygame.joystick.get_count() == 0:
            self._on_lost()
        if self._lost and self.config.on_disconnect == "raise":
            self._joystick = None
            raise GamepadDisconnectedError(
                f"focal_gamepad: {self._joystick_name!r} disconnected (unplugged, out of range or batteries "
                "flat). Motion commands stop; reconnect the pad and run connect() again, or set "
                "--teleop.on_disconnect=zero to keep recording with zero motion until it is back."
            )

    def _on_button(self, button: int) -> None:
        m = self.config.mapping
        if button == m.success_button:
            self._pending_events.add(TeleopEvents.SUCCESS)
        elif button == m.failure_button:
            self._pending_events.add(TeleopEvents.FAILURE)
        elif button == m.rerecord_button:
            self._pending_events.add(TeleopEvents.RERECORD_EPISODE)
        elif button == m.gripper_toggle_button and self._joystick.get_button(m.deadman_button):
            self.gripper = 0.0 if self.gripper > 0.5 else 1.0

    def _on_lost(self) -> None:
        if not self._lost:
            logger.error("focal_gamepad: %r disconnected; sending zero motion", self._joystick_name)
        self._lost = True

    def _try_reattach(self) -> None:
        joystick = self._find_joystick()
        if joystick is not None and joystick.get_name() == self._joystick_name:
            self._adopt(joystick)
            logger.warning("focal_gamepad: %r reconnected", self._joystick_name)
