"""``diffusion_ema``: LeRobot's ``diffusion`` policy with an EMA copy of its network on DP3's schedule.

Importing this package registers ``--policy.type=diffusion_ema`` with LeRobot.
"""

from lerobot_focal.policy.diffusion_ema.configuration_diffusion_ema import DiffusionEmaConfig
from lerobot_focal.policy.diffusion_ema.modeling_diffusion_ema import DiffusionEmaPolicy
from lerobot_focal.policy.diffusion_ema.processor_diffusion_ema import make_diffusion_ema_pre_post_processors

__all__ = ["DiffusionEmaConfig", "DiffusionEmaPolicy", "make_diffusion_ema_pre_post_processors"]
