"""Robots the plugin registers with LeRobot (`--robot.type=...`)."""

from .ur10e import UR10e, UR10eConfig

__all__ = ["UR10e", "UR10eConfig"]
