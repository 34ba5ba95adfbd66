"""``--teleop.type=focal_gamepad``: 6-DoF end-effector deltas + gripper from a gamepad (F710 map by default)."""

from .config_focal_gamepad import FocalGamepadConfig, GamepadMapping
from .focal_gamepad import GRIPPER_NAME, VELOCITY_NAMES, FocalGamepad, GamepadDisconnectedError

__all__ = [
    "VELOCITY_NAMES",
    "GRIPPER_NAME",
    "FocalGamepad",
    "FocalGamepadConfig",
    "GamepadDisconnectedError",
    "GamepadMapping",
]
