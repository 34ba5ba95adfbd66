"""Teleoperators the plugin adds. Importing this package registers them with LeRobot's config registry."""

from .focal_gamepad import FocalGamepad, FocalGamepadConfig

__all__ = ["FocalGamepad", "FocalGamepadConfig"]
