"""Configuration of ``--teleop.type=focal_gamepad``.

The button/axis numbers are SDL joystick indices as pygame reports them. The defaults are the Logitech F710 in
XInput mode (switch on the controller's back at "X") on Linux, where the kernel's ``xpad`` driver exposes it:

======  ====================  =====================================================================
Index   Physical control      Use
======  ====================  =====================================================================
axis 0  left stick X          y (translation) / roll (rotation mode)
axis 1  left stick Y          x (translation) / pitch (rotation mode)
axis 2  LT (-1 rest, +1 full) open the gripper
axis 3  right stick X         yaw
axis 4  right stick Y         z
axis 5  RT (-1 rest, +1 full) close the gripper
btn 0   A                     toggle gripper fully open / fully closed
btn 1   B                     end episode: failure
btn 2   X                     end episode: re-record
btn 3   Y                     end episode: success
btn 4   LB                    deadman: nothing moves unless held
btn 5   RB                    rotation mode: left stick gives roll/pitch instead of x/y
btn 6   Back                  (unused)
btn 7   Start                 (unused)
btn 8   Logitech (guide)      (unused)
btn 9   left stick click      (unused)
btn 10  right stick click     (unused)
hat 0   D-pad                 up / down: next / previous speed level
======  ====================  =====================================================================

On Windows (XInput through SDL) the F710 reports axes as LX 0, LY 1, RX 2, RY 3, LT 4, RT 5 and buttons
A 0, B 1, X 2, Y 3, LB 4, RB 5, Back 6, Start 7, LS 8, RS 9: set ``mapping`` accordingly, e.g.
``--teleop.mapping.right_x_axis=2 --teleop.mapping.right_y_axis=3 --teleop.mapping.left_trigger_axis=4``.
In DirectInput mode (switch at "D") the layout differs again; use XInput.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from lerobot.teleoperators.config import TeleoperatorConfig

from lerobot_focal.config_errors import reports_config_errors, require_in_range, require_non_negative, require_positive


@dataclass
class GamepadMapping:
    """Which SDL axis/button/hat index drives each function (defaults: F710, XInput mode, Linux)."""

    left_x_axis: int = 0
    left_y_axis: int = 1
    left_trigger_axis: int = 2
    right_x_axis: int = 3
    right_y_axis: int = 4
    right_trigger_axis: int = 5
    gripper_toggle_button: int = 0  # A
    failure_button: int = 1  # B
    rerecord_button: int = 2  # X
    success_button: int = 3  # Y
    deadman_button: int = 4  # LB
    rotation_button: int = 5  # RB
    speed_hat: int = 0  # D-pad


@TeleoperatorConfig.register_subclass("focal_gamepad")
@reports_config_errors("--teleop.type=focal_gamepad")
@dataclass
class FocalGamepadConfig(TeleoperatorConfig):
    # Which joystick: the first whose name contains `name_contains` (case-insensitive) if set, else this index.
    joystick_index: int = 0
    name_contains: str | None = None
    # Stick deflection below this is treated as zero; the rest is rescaled so output is continuous from 0.
    deadzone: float = 0.12
    # TCP velocities at full deflection and speed factor 1.0 (m/s, rad/s). The robot's safety filter caps them
    # again at its own limits (SafetyConfig.max_linear_speed / max_angular_speed).
    max_linear_speed: float = 0.15
    max_angular_speed: float = 0.9
    # Speed factors the D-pad cycles through; starts at `initial_speed_level` (an index into the list).
    speed_levels: list[float] = field(default_factory=lambda: [0.25, 0.5, 1.0])
    initial_speed_level: int = 1
    # Gripper command is an opening fraction (1 = open, 0 = closed); a held trigger moves it by this per call.
    gripper_step: float = 0.05
    initial_gripper: float = 1.0
    # A trigger counts as pressed above this (0 = rest, 1 = fully pressed). F710 triggers read mid-range until
    # first touched after connection, so keep this above 0.5.
    trigger_threshold: float = 0.6
    # Multiplies each output (x, y, z, roll, pitch, yaw velocities) to flip a direction without remapping.
    signs: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    # What a gamepad that disappears does: "raise" (GamepadDisconnectedError from get_action) or "zero"
    # (log an error, return zero deltas and the last gripper command until the same pad is plugged back in).
    on_disconnect: str = "raise"
    mapping: GamepadMapping = field(default_factory=GamepadMapping)

    def __post_init__(self) -> None:
        require_in_range("deadzone", self.deadzone, 0.0, 1.0, high_open=True)
        require_positive(max_linear_speed=self.max_linear_speed, max_angular_speed=self.max_angular_speed)
        require_non_negative(joystick_index=self.joystick_index)
        if not self.speed_levels or not all(math.isfinite(s) and s > 0 for s in self.speed_levels):
            raise ValueError(f"speed_levels must be positive factors, got {self.speed_levels}")
        if not 0 <= self.initial_speed_level < len(self.speed_levels):
            raise ValueError(
                f"initial_speed_level {self.initial_speed_level} is not an index into speed_levels {self.speed_levels}"
            )
        if len(self.signs) != 6 or not all(math.isfinite(s) and s != 0 for s in self.signs):
            raise ValueError(
                f"signs needs 6 finite non-zero factors (x y z roll pitch yaw; -1 flips one), got {self.signs}"
            )
        require_in_range("initial_gripper", self.initial_gripper, 0.0, 1.0)
        require_in_range("gripper_step", self.gripper_step, 0.0, 1.0, low_open=True,
                         why="It moves the opening fraction (0 closed, 1 open) per call while a trigger is held.")
        require_in_range("trigger_threshold", self.trigger_threshold, 0.0, 1.0, low_open=True, high_open=True,
                         why="Triggers read 0 at rest and 1 fully pressed.")
        if self.on_disconnect not in ("raise", "zero"):
            raise ValueError(f"on_disconnect must be 'raise' or 'zero', got {self.on_disconnect!r}")
        indices = {f.name: getattr(self.mapping, f.name) for f in fields(self.mapping)}
        negative = {name: index for name, index in indices.items() if index < 0}
        if negative:
            raise ValueError(f"mapping indices are SDL axis/button/hat numbers, ≥ 0; got {negative}")
