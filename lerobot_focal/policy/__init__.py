"""The `focal` policy, laid out as LeRobot expects (configuration_*, modeling_*, processor_*)."""

# Imported for their registration: --policy.type=diffusion_ema, diffusion_fco and dp3.
from lerobot_focal.policy import diffusion_ema, diffusion_fco, dp3  # noqa: F401
from lerobot_focal.policy.configuration_focal import ABLATIONS, FocalConfig, FocalConfigError
from lerobot_focal.policy.modeling_focal import FocalPolicy
from lerobot_focal.policy.processor_focal import make_focal_pre_post_processors

__all__ = ["ABLATIONS", "FocalConfig", "FocalConfigError", "FocalPolicy", "make_focal_pre_post_processors"]
