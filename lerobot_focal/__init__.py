"""FocalPolicy for LeRobot.

Importing this package registers, with LeRobot's registries, everything the project adds:
the ``focal`` policy (``--policy.type=focal``) and, as they land, the simulation env configs, the UR-10e
robot and the gamepad teleoperator.
"""

from lerobot_focal.policy import FocalConfig, FocalPolicy, make_focal_pre_post_processors

__all__ = ["FocalConfig", "FocalPolicy", "make_focal_pre_post_processors"]
