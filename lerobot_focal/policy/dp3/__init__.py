"""``dp3``: 3D Diffusion Policy (point cloud + agent state) on LeRobot's diffusion U-Net, with diffusion_ema's EMA.

Importing this package registers ``--policy.type=dp3`` with LeRobot.
"""

from lerobot_focal.policy.dp3.configuration_dp3 import DP3Config
from lerobot_focal.policy.dp3.modeling_dp3 import DP3Policy
from lerobot_focal.policy.dp3.processor_dp3 import make_dp3_pre_post_processors

__all__ = ["DP3Config", "DP3Policy", "make_dp3_pre_post_processors"]
