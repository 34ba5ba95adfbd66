"""``diffusion_fco``: LeRobot's ``diffusion`` policy trained with the Foresight Composite Objective ("DP w. FCO").

Importing this package registers ``--policy.type=diffusion_fco`` with LeRobot.
"""

from lerobot_focal.policy.diffusion_fco.configuration_diffusion_fco import DiffusionFcoConfig
from lerobot_focal.policy.diffusion_fco.modeling_diffusion_fco import DiffusionFcoPolicy
from lerobot_focal.policy.diffusion_fco.processor_diffusion_fco import make_diffusion_fco_pre_post_processors

__all__ = ["DiffusionFcoConfig", "DiffusionFcoPolicy", "make_diffusion_fco_pre_post_processors"]
