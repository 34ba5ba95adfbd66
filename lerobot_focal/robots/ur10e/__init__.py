"""UR-10e robot (`--robot.type=ur10e`): real arm over RTDE or its MuJoCo twin, with safety in the driver.

Importing this package only registers the config; MuJoCo and ur_rtde are imported when a backend is built.
"""

from .config_ur10e import UR10eConfig
from .safety import RobotFaultError, SafetyConfig, UnsafeActionError
from .ur10e import UR10e

__all__ = ["RobotFaultError", "SafetyConfig", "UR10e", "UR10eConfig", "UnsafeActionError"]
