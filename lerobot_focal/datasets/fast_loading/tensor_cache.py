"""The in-memory tensor cache of one LeRobot ``DatasetReader``: its numeric columns as torch tensors.

Built once per reader, when LeRobot loads the (already episode-filtered) HF dataset, by
:mod:`lerobot_focal.datasets.fast_loading.fast_reader`, which patches LeRobot's reader to gather frames and their
delta-timestamp windows from it by tensor indexing. Columns that are not plain numeric arrays (images,
language) are left out and keep LeRobot's formatted path. A dataset larger than
``LEROBOT_FOCAL_FAST_READER_MAX_MB`` (default 4096) is not cached.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from typing import Any

import torch

logger = logging.getLogger(__name__)

ENV_MAX_MB = "LEROBOT_FOCAL_FAST_READER_MAX_MB"
DEFAULT_MAX_MB = 4096.0


@dataclass
class TensorCache:
    """Numeric columns of one reader's HF dataset as tensors, plus the per-episode bounds."""

    source: Any  # the datasets.Dataset it was built from (identity is checked on every read)
    transform: Any  # the format transform that dataset had (stock: hf_transform_to_torch)
    default_dtype: torch.dtype  # torch.tensor(python floats) gives this dtype; cached floats use it
    column_order: list[str]
    columns: dict[str, torch.Tensor]  # cached columns, row-aligned with `source`
    rest: Any  # `source` restricted to the uncached columns (stock formatting), or None
    ep_from: list[int]  # dataset_from_index per episode position in meta.episodes
    ep_to: list[int]
    rel_of_abs: torch.Tensor | None  # absolute frame index -> row, -1 where absent (episode-filtered only)
    task_names: list[str]
    nbytes: int
    _deltas_src: Any = None
    _deltas: dict[str, torch.Tensor] = field(default_factory=dict)

    def deltas(self, delta_indices: dict[str, list[int]]) -> dict[str, torch.Tensor]:
        if delta_indices is not self._deltas_src:
            self._deltas = {k: torch.tensor(list(v), dtype=torch.int64) for k, v in delta_indices.items()}
            self._deltas_src = delta_indices
        return self._deltas


def _numeric_value_dtype(feature: Any) -> str | None:
    """The Arrow value dtype of a fixed-shape numeric feature (Value, fixed-length List/Sequence, ArrayND)."""
    import datasets

    if isinstance(feature, datasets.Value):
        return feature.dtype
    array_types = tuple(getattr(datasets, n) for n in ("Array2D", "Array3D", "Array4D", "Array5D"))
    if isinstance(feature, array_types):
        return feature.dtype
    list_types = tuple(t for t in (getattr(datasets, "List", None), getattr(datasets, "Sequence", None)) if t)
    if isinstance(feature, list_types) and getattr(feature, "length", -1) not in (None, -1):
        return _numeric_value_dtype(feature.feature)
    return None


def _target_dtype(value_dtype: str) -> torch.dtype | None:
    """The dtype ``torch.tensor`` gives the Python values the stock formatter makes of this Arrow dtype."""
    if value_dtype == "bool":
        return torch.bool
    if value_dtype.startswith("float") or value_dtype in ("double", "halffloat"):
        return torch.get_default_dtype()  # Python float -> default dtype
    if value_dtype.startswith("int") or value_dtype in ("uint8", "uint16", "uint32"):
        return torch.int64  # Python int -> int64 (uint64 may not fit: left to the stock path)
    return None


def _max_bytes() -> float:
    try:
        return float(os.environ.get(ENV_MAX_MB, DEFAULT_MAX_MB)) * 2**20
    except ValueError:
        return DEFAULT_MAX_MB * 2**20


def build_cache(reader: Any, stock_transform: Any) -> TensorCache | None:
    """Convert `reader.hf_dataset`'s numeric columns to tensors; None (stock path) if it should not be cached,
    e.g. when its format is not LeRobot's stock `stock_transform` (`hf_transform_to_torch`)."""
    import numpy as np
    from lerobot.datasets.language import LANGUAGE_COLUMNS

    hf = reader.hf_dataset
    if hf is None or len(hf) == 0:
        return None
    fmt = hf.format
    transform = (fmt.get("format_kwargs") or {}).get("transform")
    if fmt.get("type") != "custom" or transform is not stock_transform:
        logger.info("fast reader: HF dataset format is not LeRobot's stock transform; using the stock reader")
        return None

    order = list(hf.column_names)
    targets: dict[str, torch.dtype] = {}
    for name in order:
        if name in LANGUAGE_COLUMNS:
            continue
        value_dtype = _numeric_value_dtype(hf.features[name])
        target = _target_dtype(value_dtype) if value_dtype else None
        if target is not None:
            targets[name] = target

    # Size estimate from the Arrow buffers, scaled to the target itemsize.
    table = hf.data
    estimate = 0
    for name, target in targets.items():
        value_dtype = np.dtype(_numeric_value_dtype(hf.features[name]).replace("double", "float64"))
        scale = torch.empty((), dtype=target).element_size() / max(value_dtype.itemsize, 1)
        estimate += int(table.column(name).nbytes * scale)
    if estimate > _max_bytes():
        logger.warning(
            "fast reader: %.0f MB of numeric columns exceeds %s=%.0f MB; this dataset uses the stock reader",
            estimate / 2**20, ENV_MAX_MB, _max_bytes() / 2**20,
        )
        return None

    columns: dict[str, torch.Tensor] = {}
    nbytes = 0
    for name, target in targets.items():
        arr = hf.with_format("numpy", columns=[name])[:][name]
        if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "biuf" or arr.shape[0] != len(hf):
            continue  # ragged or odd: stock path for this column
        if arr.dtype.kind == "u" and arr.dtype.itemsize == 8:
            continue
        np_target = torch.empty((), dtype=target).numpy().dtype
        tensor = torch.from_numpy(np.array(arr, dtype=np_target, copy=True, order="C"))
        columns[name] = tensor
        nbytes += tensor.numel() * tensor.element_size()

    if "index" not in columns or "episode_index" not in columns or "task_index" not in columns:
        return None
    rest_names = [n for n in order if n not in columns]
    rest = hf.select_columns(rest_names).with_transform(transform) if rest_names else None

    episodes = reader._meta.episodes
    ep_from = [int(v) for v in episodes["dataset_from_index"]]
    ep_to = [int(v) for v in episodes["dataset_to_index"]]

    rel_of_abs = None
    if reader._absolute_to_relative_idx is not None:
        absolute = columns["index"]
        rel_of_abs = torch.full((int(absolute.max()) + 1,), -1, dtype=torch.int64)
        rel_of_abs[absolute] = torch.arange(len(absolute), dtype=torch.int64)

    return TensorCache(
        source=hf,
        transform=transform,
        default_dtype=torch.get_default_dtype(),
        column_order=order,
        columns=columns,
        rest=rest,
        ep_from=ep_from,
        ep_to=ep_to,
        rel_of_abs=rel_of_abs,
        task_names=[str(t) for t in reader._meta.tasks.index],
        nbytes=nbytes,
    )


def cache_is_current(reader: Any, cache: TensorCache | None) -> bool:
    """Whether `cache` still mirrors the reader's dataset: the same table, default dtype and transform (a
    reader whose dataset LeRobot replaced or re-formatted must rebuild it)."""
    return (
        cache is not None
        and cache.source is reader.hf_dataset
        and cache.default_dtype == torch.get_default_dtype()
        and (reader.hf_dataset.format.get("format_kwargs") or {}).get("transform") is cache.transform
    )


def cache_rows(cache: TensorCache, abs_indices: torch.Tensor) -> torch.Tensor:
    """The cache's rows of the dataset's absolute frame indices (a dataset restricted to some episodes keeps
    only theirs); an index outside them raises KeyError, as the stock reader's lookup does."""
    if cache.rel_of_abs is None:
        return abs_indices
    rel = cache.rel_of_abs[abs_indices]
    if bool((rel < 0).any()):
        missing = int(abs_indices[rel < 0][0])
        raise KeyError(missing)  # what the stock dict lookup raises
    return rel
