"""Pre/post-processing for ``diffusion_ema``: LeRobot's ``diffusion`` pipelines, unchanged.

LeRobot resolves ``make_<type>_pre_post_processors`` in the sibling ``processor_*`` module of the config class;
this thin function is that entry point for ``--policy.type=diffusion_ema``.
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.policies.diffusion.processor_diffusion import make_diffusion_pre_post_processors
from lerobot.processor import PolicyAction, PolicyProcessorPipeline

from lerobot_focal.policy.diffusion_ema.configuration_diffusion_ema import DiffusionEmaConfig


def make_diffusion_ema_pre_post_processors(
    config: DiffusionEmaConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """The ``diffusion`` policy's pipelines (normalise inputs/action, batch, device; unnormalise action)."""
    return make_diffusion_pre_post_processors(config, dataset_stats)
