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
* ``python -m lerobot_focal.datasets.fast_loading.fast_reader <lerobot-train arguments>``: installs, then runs LeRobot's
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
from typing import Any

from lerobot_focal.datasets.fast_loading.tensor_cache import build_cache, cache_is_current, cache_rows

logger = logging.getLogger(__name__)

ENV_VAR = "LEROBOT_FOCAL_FAST_READER"

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


# ------------------------------------------------------------------------------ the methods patched in
def _build_index_mapping(self) -> None:
    _ORIGINALS["DatasetReader._build_index_mapping"](self)
    self._focal_cache = None
    try:
        self._focal_cache = build_cache(self, _ORIGINALS.get("hf_transform_to_torch"))
    except Exception as exc:  # noqa: BLE001 - never let the optimisation break loading
        logger.warning("fast reader: could not cache the dataset (%s: %s); using the stock reader",
                       type(exc).__name__, exc)
    if self._focal_cache is not None:
        logger.info("fast reader: %d columns cached in memory (%.1f MB)",
                    len(self._focal_cache.columns), self._focal_cache.nbytes / 2**20)


def get_item(self, idx) -> dict:
    """``DatasetReader.get_item`` reading from the tensor cache; same keys, order, dtypes and values."""
    cache = getattr(self, "_focal_cache", None)
    if not cache_is_current(self, cache):
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
                query_result[key] = cols[key].index_select(0, cache_rows(cache, clamped))
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
                    query_timestamps[key] = cols["timestamp"][cache_rows(cache, query_indices[key])].tolist()
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
    """``python -m lerobot_focal.datasets.fast_loading.fast_reader <lerobot-train args>``: LeRobot's training entry
    point with the fast reader installed first (the loop itself is LeRobot's, unchanged)."""
    args = sys.argv[1:] if argv is None else argv
    install(force=os.environ.get(ENV_VAR, "").strip().lower() == "force")
    from lerobot.scripts.lerobot_train import main as lerobot_train_main

    sys.argv = ["lerobot-train", *args]
    lerobot_train_main()


if __name__ == "__main__":
    main()
