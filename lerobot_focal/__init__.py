"""FocalPolicy for LeRobot.

Importing this package registers, with LeRobot's registries, everything the project adds: the ``focal``
policy (``--policy.type=focal``), the ``focal_metaworld`` / ``focal_adroit`` env configs, the ``ur10e``
robot and the ``focal_gamepad`` teleoperator. Registration imports only config classes: simulators, ur_rtde,
pymodbus and pygame are imported when an env, robot or teleoperator is actually built, so the plugin loads
without the optional extras.
"""

from lerobot_focal import envs, robots, teleoperators  # noqa: F401  (registration side effects)
from lerobot_focal.datasets.fast_loading.fast_reader import install_from_env as _install_fast_reader
from lerobot_focal.policy import FocalConfig, FocalPolicy, make_focal_pre_post_processors

# Opt-in in-memory dataset reader (docs/data_throughput.md): a no-op unless LEROBOT_FOCAL_FAST_READER=1.
_install_fast_reader()

__all__ = ["FocalConfig", "FocalPolicy", "make_focal_pre_post_processors"]
