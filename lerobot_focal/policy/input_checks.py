"""Checks that stop bad data before it silently changes what `focal` learns or does.

* :func:`check_dataset_stats` — when the policy and its processors are built from a dataset: one NaN or inf
  in a feature makes LeRobot's statistics of that dimension non-finite (``max=inf``, ``mean=nan``); min-max
  normalisation then maps the dimension to a constant for every frame and training runs to the end with that
  input dead (or fails much later on NaN batches without saying why). The check names the feature, the
  dimension, and — read from the dataset's parquet files — the episode and frame that hold the bad value.
* :class:`FocalInputShapeStep` — a preprocessor step, before normalisation, that compares each observation the
  policy reads with the shape it was trained on. LeRobot's normaliser would otherwise fail on a mismatch with
  a bare broadcasting error ("The size of tensor a (3) must match the size of tensor b (6)").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lerobot.configs.types import PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry

INPUT_SHAPE_STEP = "focal_input_shape_check"
_STATS_CHECKED = ("min", "max", "mean", "std")
_MAX_REPORTED = 5


class DatasetStatsError(ValueError):
    """The dataset's normalisation statistics of a feature the policy uses are NaN or infinite."""


def _as_array(value: Any) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    return np.asarray(value, dtype=np.float64)


def find_nonfinite_frames(root: str | Path, key: str, limit: int = _MAX_REPORTED) -> list[tuple[int, int, int, float]]:
    """(episode, frame, flat dimension, value) of the first `limit` NaN/inf entries of `key` in the dataset's
    parquet files at `root`; empty when the feature is not stored in parquet (images, videos) or unreadable."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    hits: list[tuple[int, int, int, float]] = []
    for path in sorted(Path(root).glob("data/**/*.parquet")):
        try:
            table = pq.read_table(path, columns=[key, "episode_index", "frame_index"])
        except Exception:  # noqa: BLE001 - a missing column or unreadable file only means "not found here"
            return hits
        column = table.column(key).combine_chunks()
        leaves = column
        while pa.types.is_list(leaves.type) or pa.types.is_fixed_size_list(leaves.type) or pa.types.is_large_list(
            leaves.type
        ):
            leaves = leaves.flatten()
        values = np.asarray(leaves.to_numpy(zero_copy_only=False), dtype=np.float64).reshape(len(table), -1)
        rows, dims = np.nonzero(~np.isfinite(values))
        episodes = table.column("episode_index").to_numpy()
        frames = table.column("frame_index").to_numpy()
        for r, d in zip(rows, dims, strict=True):
            hits.append((int(episodes[r]), int(frames[r]), int(d), float(values[r, d])))
            if len(hits) >= limit:
                return hits
    return hits


def check_dataset_stats(
    stats: dict[str, dict[str, Any]] | None, keys: list[str], meta: Any = None
) -> None:
    """Raise :class:`DatasetStatsError` when a statistic of one of `keys` is NaN/inf (see the module docstring).

    `meta` (a LeRobotDatasetMetadata, optional) locates the dataset, to name the episodes and frames at fault.
    """
    root = getattr(meta, "root", None)
    repo_id = getattr(meta, "repo_id", None) or "<repo_id>"
    if not stats:
        return
    problems = []
    for key in keys:
        feature_stats = stats.get(key) or {}
        bad: dict[int, list[str]] = {}
        for name in _STATS_CHECKED:
            if name not in feature_stats:
                continue
            value = _as_array(feature_stats[name]).reshape(-1)
            for dim in np.nonzero(~np.isfinite(value))[0]:
                bad.setdefault(int(dim), []).append(f"{name}={value[dim]}")
        if not bad:
            continue
        dims = "; ".join(f"dimension {d}: {', '.join(v)}" for d, v in sorted(bad.items()))
        text = f"'{key}' ({dims})"
        hits = find_nonfinite_frames(root, key) if root is not None else []
        if hits:
            shown = ", ".join(f"episode {e} frame {f} has {key}[{d}] = {v}" for e, f, d, v in hits)
            episodes = sorted({e for e, *_ in hits})
            text += (
                f". In the dataset: {shown}{' …' if len(hits) == _MAX_REPORTED else ''}. To drop those episodes: "
                f"lerobot-edit-dataset --repo_id {repo_id} --root {root} --operation.type delete_episodes "
                f"--operation.episode_indices \"{episodes}\""
            )
        problems.append(text)
    if problems:
        raise DatasetStatsError(
            "The dataset's normalisation statistics are not finite for "
            + " | ".join(problems)
            + ". A NaN or inf in a feature poisons its statistics: that dimension would normalise to a constant "
            "(or NaN) for every frame, and the policy would train without it. Fix the data: repair or delete the "
            "frames or episodes holding NaN/inf (LeRobot recomputes the statistics when the dataset is edited), "
            "or fix the recording source that produced them."
        )


@ProcessorStepRegistry.register(INPUT_SHAPE_STEP)
@dataclass
class FocalInputShapeStep(ObservationProcessorStep):
    """Refuses an observation whose per-frame shape differs from the one the policy was trained on.

    `shapes` maps each observation key the policy reads to its trained shape (without batch/time axes); a −1
    matches any size (a point cloud's point count: the encoder max-pools over points, so a cloud of another
    size is a valid input, as DP3 trains on 1024 points and evaluates on 512). A key absent from the
    observation is left to the policy, which names what it needs.
    """

    shapes: dict[str, list[int]] = field(default_factory=dict)

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        for key, expected in self.shapes.items():
            value = observation.get(key)
            if value is None or not hasattr(value, "shape"):
                continue
            got = tuple(value.shape)
            tail = got[len(got) - len(expected) :]
            if len(got) < len(expected) or any(e not in (-1, g) for e, g in zip(expected, tail, strict=True)):
                raise ValueError(self._message(key, got, tuple(expected)))
        return observation

    @staticmethod
    def _message(key: str, got: tuple[int, ...], expected: tuple[int, ...]) -> str:
        sizes = ["P" if e == -1 else str(e) for e in expected]  # -1: any point count
        trained = f"({', '.join(sizes)}{',' if len(sizes) == 1 else ''})"
        text = (
            f"'{key}' has shape {got}, but this policy was trained on {trained} per frame (with leading batch/time "
            "axes)."
        )
        if len(expected) == 2 and expected[-1] in (3, 6) and len(got) >= 2 and got[-1] in (3, 6):
            kinds = {3: "xyz (P, 3)", 6: "xyz+rgb (P, 6)"}
            text += (
                f" The checkpoint expects {kinds[expected[-1]]} point clouds and was given {kinds[got[-1]]}: give it "
                f"clouds with {expected[-1]} channels (env/robot setting), or use a checkpoint trained on "
                f"{got[-1]}-channel clouds (use_pointcloud_color={'true' if got[-1] == 6 else 'false'})."
            )
        else:
            text += " Give it the observations it was trained with, or train a policy on these."
        return text

    def get_config(self) -> dict[str, Any]:
        return {"shapes": {k: list(v) for k, v in self.shapes.items()}}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features
