"""Pre/post-processing pipelines for `focal`: LeRobot's standard policy pipeline plus per-channel point-cloud stats.

Pre:  rename → add batch dim → device → normalise (used inputs + action).   Post: unnormalise action → cpu.

Only the observations the policy reads are normalised. A robot or dataset may carry more (a uint16 depth
map, joint velocities), and LeRobot's default normaliser would touch every input feature — a uint16 depth
frame then fails to convert ("value cannot be converted to type uint16 without overflow").

Point clouds: LeRobot has no point-cloud feature type, so `observation.pointcloud` is a STATE feature and is
MIN_MAX-normalised per xyz channel (DP3's "limits" normaliser). Stats written by LeRobot 0.6.1 for a (P, 3)
feature are already per channel, shape (3,); stats computed elsewhere can be per point slot, shape (P, 3),
which is meaningless after farthest-point sampling (slot i holds a different point every frame). Such stats
are pooled to per channel here, before they are stored in the normaliser step — so the saved pipeline
reloads with correct stats and needs no custom step.
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.processor import NormalizerProcessorStep, PolicyAction, PolicyProcessorPipeline
from lerobot.processor.factory import make_default_policy_processor_steps, make_policy_processor_pipelines

from lerobot_focal.policy.configuration_focal import FocalConfig


def per_channel_pointcloud_stats(stats: dict[str, Any], num_channels: int) -> dict[str, Any]:
    """Pool per-point-slot statistics (P, C) into per-channel ones (C,). Per-channel stats pass unchanged.

    min/max pool exactly; mean is the mean over slots (equal counts); std pools the second moments;
    any other statistic (quantiles, counts) is averaged over slots, an approximation noted here because
    focal normalises point clouds with MIN_MAX.
    """
    out: dict[str, Any] = {}
    tensors = {k: torch.as_tensor(v, dtype=torch.float64) for k, v in stats.items()}
    for name, value in tensors.items():
        if value.ndim < 2 or value.shape[-1] != num_channels:
            out[name] = stats[name]
            continue
        flat = value.reshape(-1, num_channels)
        if name == "min":
            pooled = flat.min(0).values
        elif name == "max":
            pooled = flat.max(0).values
        elif name == "std" and "mean" in tensors:
            means = tensors["mean"].reshape(-1, num_channels)
            second = (flat.pow(2) + means.pow(2)).mean(0)
            pooled = (second - means.mean(0).pow(2)).clamp_min(0).sqrt()
        else:
            pooled = flat.mean(0)
        out[name] = pooled.to(torch.float32)
    return out


def make_focal_pre_post_processors(
    config: FocalConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    stats = dict(dataset_stats) if dataset_stats is not None else None
    key = config.pointcloud_key
    if stats is not None and key in stats and key in config.input_features:
        channels = config.input_features[key].shape[-1]
        stats[key] = per_channel_pointcloud_stats(stats[key], channels)
    s = make_default_policy_processor_steps(config, stats)
    used = {k: config.input_features[k] for k in config.used_observation_keys}
    normalize = NormalizerProcessorStep(
        features={**used, **config.output_features}, norm_map=config.normalization_mapping, stats=stats
    )
    return make_policy_processor_pipelines(
        input_steps=[s.rename_observations, s.add_batch_dim, s.to_device, normalize],
        output_steps=[s.unnormalize, s.to_cpu],
    )
