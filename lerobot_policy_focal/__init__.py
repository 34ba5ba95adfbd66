"""LeRobot plugin entry point.

LeRobot's ``register_third_party_plugins()`` imports every installed distribution whose name starts with
``lerobot_policy_`` *as a module of that name*. This module exists only so that this import happens; it
registers everything the project provides (policy ``focal``, env configs, robot, teleoperator).
"""

from lerobot_focal import *  # noqa: F401,F403
from lerobot_focal import __all__  # noqa: F401
