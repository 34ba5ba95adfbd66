"""Pre/post-processing pipelines for `focal`: LeRobot's standard policy pipeline, `focal`'s statistics.

Pre:  rename → add batch dim → (depth → point cloud) → device → shape check → normalise (used inputs + action).
Post: unnormalise action → cpu.

Only the observations the policy reads are normalised. A robot or dataset may carry more (a uint16 depth
map, joint velocities), and LeRobot's default normaliser would touch every input feature — a uint16 depth
frame then fails to convert ("value cannot be converted to type uint16 without overflow"). The statistics are
`lerobot_focal.policy.stats.adapt_dataset_stats` of the dataset's; the depth step is
`lerobot_focal.policy.depth_pointcloud_step`.
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.processor import NormalizerProcessorStep, PolicyAction, PolicyProcessorPipeline
from lerobot.processor.factory import make_default_policy_processor_steps, make_policy_processor_pipelines
from lerobot.utils.constants import ACTION

from lerobot_focal.policy.configuration_focal import FocalConfig
from lerobot_focal.policy.depth_pointcloud_step import (  # noqa: F401  (re-exported: the step's public home)
    DEPTH_TO_POINTCLOUD_STEP,
    DepthToPointCloudProcessorStep,
    make_depth_to_pointcloud_step,
)
from lerobot_focal.policy.input_checks import FocalInputShapeStep, check_dataset_stats
from lerobot_focal.policy.lerobot_compat import refuse_stacked_ema
from lerobot_focal.policy.stats import adapt_dataset_stats


def make_focal_pre_post_processors(
    config: FocalConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    # lerobot-train (LeRobot main) builds the processors after the policy and before its own EMA: refuse a second
    # EMA here, before the first step.
    refuse_stacked_ema(config)
    # Before any statistic is used or adapted: a NaN/inf in the data shows up here as non-finite stats.
    meta = getattr(config, "_runtime_dataset_meta", None)  # set by LeRobot's make_policy
    check_dataset_stats(dataset_stats, [*config.used_observation_keys, ACTION], meta)
    stats = adapt_dataset_stats(config, dataset_stats) if dataset_stats is not None else None
    depth_step = make_depth_to_pointcloud_step(config) if config.depth_cloud.enabled else None
    used = {k: config.input_features[k] for k in config.used_observation_keys}
    s = make_default_policy_processor_steps(config, stats)
    normalize = NormalizerProcessorStep(
        features={**used, **config.output_features}, norm_map=config.normalization_mapping, stats=stats
    )
    # Before the normaliser, which would fail on a wrong shape with a bare broadcasting error.
    # Any number of points (-1): the cloud encoder max-pools over them.
    shape_check = FocalInputShapeStep(shapes={
        k: [-1, ft.shape[-1]] if k == config.used_pointcloud_key else list(ft.shape) for k, ft in used.items()
    })
    # The cloud is made after batching (so an unbatched frame works too) and before the device move (numpy).
    extra = [depth_step] if depth_step is not None else []
    return make_policy_processor_pipelines(
        input_steps=[s.rename_observations, s.add_batch_dim, *extra, s.to_device, shape_check, normalize],
        output_steps=[s.unnormalize, s.to_cpu],
    )
