"""Normalisation statistics as `focal` uses them, from whatever statistics a dataset carries.

* Point clouds: LeRobot has no point-cloud feature type, so `observation.pointcloud` is a STATE feature and is
  MIN_MAX-normalised per xyz channel (DP3's "limits" normaliser). Stats written by LeRobot 0.6.1 for a (P, 3)
  feature are already per channel, shape (3,); stats computed elsewhere can be per point slot, shape (P, 3),
  which is meaningless after farthest-point sampling (slot i holds a different point every frame): they are
  pooled to per channel. A cloud made from depth by the preprocessor has no dataset statistics at all: its
  statistics are the crop box (every point lies in it).
* MIN_MAX dimensions that are constant in the data keep a unit scale (see `widen_degenerate_min_max`).

`adapt_dataset_stats` applies all of it and is idempotent. It runs where LeRobot hands `focal` a dataset's
statistics: in the processor factory (training from scratch) and when the policy is built with the dataset
(`make_policy` passes `dataset_stats`), because when fine-tuning from a checkpoint (`lerobot-train
--policy.path=...`) LeRobot gives that same stats dict straight to the saved normaliser as an override.
"""

from __future__ import annotations

import logging
from typing import Any

import torch
from lerobot.configs.types import PolicyFeature
from lerobot.utils.constants import ACTION

from lerobot_focal.policy.configuration_focal import FocalConfig
from lerobot_focal.policy.input_checks import check_dataset_stats

logger = logging.getLogger(__name__)


def crop_box_stats(crop_min, crop_max) -> dict[str, torch.Tensor]:
    """Per-channel (3,) normalisation stats of a cloud cropped to the box: min/max are the box (every point
    lies in it, so MIN_MAX maps the cloud into [-1, 1] at training and at rollout alike, independent of the
    dataset), mean/std those of a uniform fill of the box (used only if STATE is switched to MEAN_STD)."""
    lo = torch.tensor([float(x) for x in crop_min], dtype=torch.float32)
    hi = torch.tensor([float(x) for x in crop_max], dtype=torch.float32)
    return {"min": lo, "max": hi, "mean": (lo + hi) / 2, "std": (hi - lo) / 12**0.5}


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


#: A MIN_MAX range narrower than this is a dimension that is (nearly) constant in the data.
DEGENERATE_RANGE = 1e-4


def widen_degenerate_min_max(
    stats: dict[str, dict[str, Any]], features: dict[str, PolicyFeature], norm_map: dict[str, Any]
) -> dict[str, dict[str, Any]]:
    """Give MIN_MAX dimensions that are constant in the data a unit scale, centred on their value.

    LeRobot's MIN_MAX divides by (max − min) and falls back to 1e-8 when they are equal, so a dimension that
    never moves in the demonstrations (an object coordinate of a task that never touches it, a second object
    absent from a task) but moves at evaluation is scaled by ~1e8 and swamps the condition. Like DP3's
    "limits" normaliser, such a dimension is shifted to 0 and left unscaled: min, max = value ∓ 1, so the
    normalised value is (x − value). Returns a new stats dict; other features and dimensions are unchanged.
    """
    out = dict(stats)
    for key, feature in features.items():
        mode = norm_map.get(feature.type.value) if hasattr(feature.type, "value") else None
        if key not in stats or str(getattr(mode, "value", mode)) != "MIN_MAX":
            continue
        entry = stats[key]
        if "min" not in entry or "max" not in entry:
            continue
        lo = torch.as_tensor(entry["min"], dtype=torch.float32)
        hi = torch.as_tensor(entry["max"], dtype=torch.float32)
        flat = (hi - lo).abs() < DEGENERATE_RANGE
        if not bool(flat.any()):
            continue
        mid = (lo + hi) / 2
        out[key] = {**entry, "min": torch.where(flat, mid - 1.0, lo), "max": torch.where(flat, mid + 1.0, hi)}
        logger.info("%s: %d dimension(s) constant in the data keep a unit scale: %s", key, int(flat.sum()),
                    torch.nonzero(flat).flatten().tolist()[:16])
    return out


def adapt_dataset_stats(config: FocalConfig, stats: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The statistics `focal`'s normaliser needs, from a dataset's (a new dict; see the module docstring)."""
    stats = dict(stats)
    key = config.pointcloud_key
    depth = config.depth_cloud
    if depth.enabled and key not in stats:
        stats[key] = crop_box_stats(depth.crop_min, depth.crop_max)
    if key in stats and key in config.input_features:
        stats[key] = per_channel_pointcloud_stats(stats[key], config.input_features[key].shape[-1])
    used = {k: config.input_features[k] for k in config.used_observation_keys}
    return widen_degenerate_min_max(stats, {**used, **config.output_features}, config.normalization_mapping)


def adopt_dataset_stats(
    config: FocalConfig, dataset_stats: dict[str, dict[str, Any]], dataset_meta: Any = None
) -> None:
    """What a policy built with a dataset (`make_policy` passes `dataset_stats`) does with its statistics.

    A NaN/inf in the data shows up as non-finite statistics: stop here, naming feature, dimension and frame (from
    `dataset_meta`), before they are adapted and silently flatten that dimension for the whole run. Fine-tuning
    from a checkpoint (`lerobot-train --policy.path=...`), LeRobot hands this very dict to the saved normaliser as
    its new statistics, bypassing the processor factory: it is adapted in place so the normaliser gets what the
    policy needs (per-channel / crop-box cloud stats, constant dimensions at unit scale). Idempotent, so the
    factory applying it again changes nothing.
    """
    check_dataset_stats(dataset_stats, [*config.used_observation_keys, ACTION], dataset_meta)
    adapted = adapt_dataset_stats(config, dataset_stats)
    dataset_stats.clear()
    dataset_stats.update(adapted)
