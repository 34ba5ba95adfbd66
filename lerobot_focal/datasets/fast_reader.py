"""An opt-in in-memory tensor cache behind LeRobot's own ``LeRobotDataset`` reader.

Why: LeRobot 0.6.1 reads every frame through ``datasets``' Python formatter (Arrow row -> nested Python
lists) and ``hf_transform_to_torch`` (one ``torch.tensor`` per value), and does that once for the frame
and once more per delta-timestamp key. On a (512, 3) point cloud that is ~25-50 ms per item, i.e. seconds
per batch of 64 on a CPU, several times the cost of the update it feeds (see docs/data_throughput.md).

What: when enabled, each ``DatasetReader`` converts the numeric columns of its (already episode-filtered)
HF dataset to torch tensors **once**, when LeRobot loads it, and ``get_item`` then gathers the frame and its
delta-timestamp windows by tensor indexing. Everything else is LeRobot's: the dataset object, the sampler,
the DataLoader, the training loop, video decoding (``_query_videos``), image transforms, depth units.
Columns that are not plain numeric arrays (PNG images, language columns) keep going through the stock
formatted path, per column. The values and dtypes are those the stock reader returns, bit for bit
(tests/datasets/test_fast_reader.py checks this against the stock reader, including the episode-boundary
padding and the ``*_is_pad`` masks).

Opt in (nothing changes unless one of these is used):

* ``LEROBOT_FOCAL_FAST_READER=1 lerobot-train ...`` once the plugin's ``__init__`` calls
  :func:`install_from_env` (every lerobot-* CLI imports the plugin before it builds the dataset);
* ``python -m lerobot_focal.datasets.fast_reader <lerobot-train arguments>``: installs, then runs LeRobot's
  own ``lerobot.scripts.lerobot_train.main`` unchanged;
* in Python: :func:`install` / :func:`uninstall`, or ``with enabled(): ...``.

Safety: the patch installs only on the LeRobot reader it was written and tested against (source hashes of
the reader methods it stands in for; ``LEROBOT_FOCAL_FAST_READER=force`` overrides), a dataset larger than
``LEROBOT_FOCAL_FAST_READER_MAX_MB`` (default 4096) stays on the stock path, any failure while building the
cache logs a warning and leaves that dataset on the stock path, and a reader whose HF dataset, format or
default dtype changed after the cache was built falls back to the stock ``get_item``.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import logging
import os
import sys
from dataclasses import dataclass, field
from typing import Any

import torch

logger = logging.getLogger(__name__)

ENV_VAR = "LEROBOT_FOCAL_FAST_READER"
ENV_MAX_MB = "LEROBOT_FOCAL_FAST_READER_MAX_MB"
DEFAULT_MAX_MB = 4096.0

# sha256[:16] of the LeRobot 0.6.1 sources this module reproduces or hooks. If LeRobot changes any of them,
# the patch does not install (a warning says so) and training runs on the stock reader.
EXPECTED_SOURCES = {
    "DatasetReader.get_item": "9a2e7319df2a8c3d",
    "DatasetReader._get_query_indices": "e101a2bd44ebc5b1",
    "DatasetReader._query_hf_dataset": "336ace4535aca2dd",
    "DatasetReader._get_query_timestamps": "6b21383c4f31c656",
    "DatasetReader._build_index_mapping": "23fed63886231e82",
    "DatasetReader._load_hf_dataset": "3625797f48b679af",
    "hf_transform_to_torch": "9cd552f68db899c9",
}

_ORIGINALS: dict[str, Any] = {}


# ----------------------------------------------------------------------------------------------- the cache
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


def build_cache(reader: Any) -> TensorCache | None:
    """Convert `reader.hf_dataset`'s numeric columns to tensors; None (stock path) if it should not be cached."""
    import numpy as np
    from lerobot.datasets.language import LANGUAGE_COLUMNS

    hf = reader.hf_dataset
    if hf is None or len(hf) == 0:
        return None
    fmt = hf.format
    transform = (fmt.get("format_kwargs") or {}).get("transform")
    if fmt.get("type") != "custom" or transform is not _ORIGINALS.get("hf_transform_to_torch"):
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


def _cache_is_current(reader: Any, cache: TensorCache | None) -> bool:
    return (
        cache is not None
        and cache.source is reader.hf_dataset
        and cache.default_dtype == torch.get_default_dtype()
        and (reader.hf_dataset.format.get("format_kwargs") or {}).get("transform") is cache.transform
    )


# ------------------------------------------------------------------------------ the methods patched in
def _build_index_mapping(self) -> None:
    _ORIGINALS["DatasetReader._build_index_mapping"](self)
    self._focal_cache = None
    try:
        self._focal_cache = build_cache(self)
    except Exception as exc:  # never let the optimisation break loading
        logger.warning("fast reader: could not cache the dataset (%s: %s); using the stock reader",
                       type(exc).__name__, exc)
    if self._focal_cache is not None:
        logger.info("fast reader: %d columns cached in memory (%.1f MB)",
                    len(self._focal_cache.columns), self._focal_cache.nbytes / 2**20)


def _rows(cache: TensorCache, abs_indices: torch.Tensor) -> torch.Tensor:
    if cache.rel_of_abs is None:
        return abs_indices
    rel = cache.rel_of_abs[abs_indices]
    if bool((rel < 0).any()):
        missing = int(abs_indices[rel < 0][0])
        raise KeyError(missing)  # what the stock dict lookup raises
    return rel


def get_item(self, idx) -> dict:
    """``DatasetReader.get_item`` reading from the tensor cache; same keys, order, dtypes and values."""
    cache = getattr(self, "_focal_cache", None)
    if not _cache_is_current(self, cache):
        return _ORIGINALS["DatasetReader.get_item"](self, idx)
    cols = cache.columns

    rest_row = cache.rest[idx] if cache.rest is not None else {}
    item = {name: (cols[name][idx].clone() if name in cols else rest_row[name]) for name in cache.column_order}
    ep_idx = item["episode_index"].item()
    abs_idx = item["index"].item()

    query_indices = None
    if self.delta_indices is not None:
        ep_start, ep_end = cache.ep_from[ep_idx], cache.ep_to[ep_idx]
        query_indices, padding, query_result = {}, {}, {}
        for key, delta in cache.deltas(self.delta_indices).items():
            wanted = abs_idx + delta
            # stock: max(ep_start, min(ep_end - 1, abs_idx + delta)); is_pad outside [ep_start, ep_end)
            clamped = wanted.clamp(max=ep_end - 1).clamp(min=ep_start)
            query_indices[key] = clamped
            padding[f"{key}_is_pad"] = (wanted < ep_start) | (wanted >= ep_end)
        for key, clamped in query_indices.items():
            if key in self._meta.video_keys:
                continue
            if key in cols:
                query_result[key] = cols[key].index_select(0, _rows(cache, clamped))
            else:  # uncached column: LeRobot's own query, on LeRobot's own dataset
                query_result.update(self._query_hf_dataset({key: clamped.tolist()}))
        item = {**item, **padding}
        for key, val in query_result.items():
            item[key] = val

    if len(self._meta.video_keys) > 0:
        current_ts = item["timestamp"].item()
        query_timestamps = {}
        for key in self._meta.video_keys:
            if query_indices is not None and key in query_indices:
                if "timestamp" in cols:
                    query_timestamps[key] = cols["timestamp"][_rows(cache, query_indices[key])].tolist()
                else:
                    query_timestamps.update(
                        self._get_query_timestamps(current_ts, {key: query_indices[key].tolist()})
                    )
            else:
                query_timestamps[key] = [current_ts]
        video_frames = self._query_videos(query_timestamps, ep_idx)
        item = {**video_frames, **item}

    if self._image_transforms is not None:
        for cam in self._meta.camera_keys:
            if cam in self._meta.depth_keys:
                continue
            item[cam] = self._image_transforms(item[cam])

    from lerobot.configs import DEPTH_METER_UNIT
    from lerobot.datasets.depth_utils import MM_PER_METRE

    for key, stored_unit in self._image_depth_units.items():
        if key in item and stored_unit is not None and stored_unit != self._depth_output_unit:
            item[key] = item[key] * MM_PER_METRE if stored_unit == DEPTH_METER_UNIT else item[key] / MM_PER_METRE

    item["task"] = cache.task_names[item["task_index"].item()]
    return item


# ----------------------------------------------------------------------------------------- install/opt-in
def _source_hashes() -> dict[str, str | None]:
    from lerobot.datasets import dataset_reader, io_utils

    objs = {name: getattr(dataset_reader.DatasetReader, name.split(".")[1])
            for name in EXPECTED_SOURCES if name.startswith("DatasetReader.")}
    objs["hf_transform_to_torch"] = io_utils.hf_transform_to_torch
    out: dict[str, str | None] = {}
    for name, obj in objs.items():
        obj = _ORIGINALS.get(name, obj)  # hash what LeRobot ships even while patched
        try:
            out[name] = hashlib.sha256(inspect.getsource(obj).encode()).hexdigest()[:16]
        except (OSError, TypeError):
            out[name] = None
    return out


def compatible() -> tuple[bool, list[str]]:
    """Whether the installed LeRobot reader is the one this module reproduces, and what differs if not."""
    hashes = _source_hashes()
    differ = [name for name, expected in EXPECTED_SOURCES.items() if hashes.get(name) != expected]
    return not differ, differ


def is_installed() -> bool:
    return bool(_ORIGINALS)


def install(force: bool = False) -> bool:
    """Patch LeRobot's ``DatasetReader`` (idempotent). Returns whether the fast reader is active."""
    if _ORIGINALS:
        return True
    from lerobot.datasets import dataset_reader, io_utils

    ok, differ = compatible()
    if not ok and not force:
        logger.warning(
            "fast reader NOT installed: LeRobot's reader differs from the one it was verified against (%s). "
            "Training uses the stock reader. Set %s=force to install anyway.", ", ".join(differ), ENV_VAR,
        )
        return False
    cls = dataset_reader.DatasetReader
    _ORIGINALS["DatasetReader.get_item"] = cls.get_item
    _ORIGINALS["DatasetReader._build_index_mapping"] = cls._build_index_mapping
    _ORIGINALS["hf_transform_to_torch"] = io_utils.hf_transform_to_torch
    cls.get_item = get_item
    cls._build_index_mapping = _build_index_mapping
    logger.info("fast reader installed on lerobot.datasets.dataset_reader.DatasetReader")
    return True


def uninstall() -> None:
    """Restore LeRobot's reader. Readers built while installed keep their cache but read through stock code."""
    if not _ORIGINALS:
        return
    from lerobot.datasets import dataset_reader

    cls = dataset_reader.DatasetReader
    cls.get_item = _ORIGINALS["DatasetReader.get_item"]
    cls._build_index_mapping = _ORIGINALS["DatasetReader._build_index_mapping"]
    _ORIGINALS.clear()


@contextlib.contextmanager
def enabled(force: bool = False):
    was = is_installed()
    active = install(force=force)
    try:
        yield active
    finally:
        if not was:
            uninstall()


def install_from_env() -> bool:
    """Install if ``LEROBOT_FOCAL_FAST_READER`` is 1/true/on/yes/force; imports nothing otherwise."""
    value = os.environ.get(ENV_VAR, "").strip().lower()
    if value in ("", "0", "false", "off", "no"):
        return False
    if value not in ("1", "true", "on", "yes", "force"):
        logger.warning("%s=%r not understood (use 1 or force); fast reader not installed", ENV_VAR, value)
        return False
    return install(force=value == "force")


def main(argv: list[str] | None = None) -> None:
    """``python -m lerobot_focal.datasets.fast_reader <lerobot-train args>``: LeRobot's training entry point
    with the fast reader installed first (the loop itself is LeRobot's, unchanged)."""
    args = sys.argv[1:] if argv is None else argv
    install(force=os.environ.get(ENV_VAR, "").strip().lower() == "force")
    from lerobot.scripts.lerobot_train import main as lerobot_train_main

    sys.argv = ["lerobot-train", *args]
    lerobot_train_main()


if __name__ == "__main__":
    main()
