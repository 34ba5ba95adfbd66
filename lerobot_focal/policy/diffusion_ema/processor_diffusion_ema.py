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
from lerobot_focal.policy.lerobot_compat import refuse_stacked_ema


def make_diffusion_ema_pre_post_processors(
    config: DiffusionEmaConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """The ``diffusion`` policy's pipelines (normalise inputs/action, batch, device; unnormalise action)."""
    refuse_stacked_ema(config)  # lerobot-train (LeRobot main) with --ema.enable=true: see lerobot_compat
    return make_diffusion_pre_post_processors(config, dataset_stats)
