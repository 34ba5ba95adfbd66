"""Pre/post-processing for ``dp3``: focal's pipelines, so both policies see the cloud normalised alike.

LeRobot resolves ``make_<type>_pre_post_processors`` in the sibling ``processor_*`` module of the config class;
this is that entry point for ``--policy.type=dp3``. LeRobot's ``diffusion`` pipeline would normalise every input
feature the dataset lists, a depth map too, with the statistics as stored; focal's normalises the features the
policy reads only, with the cloud's statistics per channel and constant dimensions at unit scale (see
``DP3Config``), and checks their shapes first.
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.processor import PolicyAction, PolicyProcessorPipeline

from lerobot_focal.policy.dp3.configuration_dp3 import DP3Config
from lerobot_focal.policy.processor_focal import make_focal_pre_post_processors


def make_dp3_pre_post_processors(
    config: DP3Config,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """focal's pipelines (normalise the cloud, state and action, batch, device; unnormalise the action)."""
    return make_focal_pre_post_processors(config, dataset_stats)
