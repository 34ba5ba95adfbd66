"""``lerobot-focal-salvage-dataset``: recover the finished episodes of a LeRobotDataset whose writer was killed.

    lerobot-focal-salvage-dataset outputs/data/ur10e_demo                 # writes outputs/data/ur10e_demo_salvaged
    lerobot-focal-salvage-dataset outputs/data/ur10e_demo --out /data/x   # or another folder

LeRobot's writer (``lerobot-record``, ``LeRobotDataset.save_episode``) keeps the data parquet file open across
episodes and buffers the episode index (``meta/episodes/``) in memory; both are written when the dataset is
finalized. A recording killed hard (SIGKILL, out of memory, power loss) leaves ``meta/info.json`` counting the
saved episodes, a data file without its footer and no episode index: LeRobot cannot open it. The frames of
every saved episode are in the data file, one row group per episode, and their camera videos were encoded
when the episode was saved.

This command (1) rebuilds the data files' footers (:mod:`lerobot_focal.datasets.repair.parquet_footer`), keeping
each complete row group; (2) places every recovered episode in the video files, in order, by its length;
(3) opens that as a read-only LeRobotDataset and writes its episodes, frame by frame, into a new dataset with
LeRobot's own writer, which computes the statistics and the episode index anew. The source folder is never
modified. Limits: the episode being recorded at the kill is lost (its frames were only in memory and in
temporary images); camera frames are decoded and encoded again (one more lossy video generation); an episode
whose video was not complete is dropped with the following ones, and the command says so.
"""

from __future__ import annotations

import json
import logging
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from lerobot_focal.console import doc_parser
from lerobot_focal.datasets.repair.parquet_footer import FooterRebuildError, rebuild_footer

logger = logging.getLogger(__name__)


class SalvageError(RuntimeError):
    pass


def _features(info: dict) -> dict[str, dict]:
    return {k: {**ft, "shape": tuple(ft["shape"])} for k, ft in info["features"].items()}


def _read_or_rebuild(path: Path, dst: Path, features: dict) -> tuple[pa.Table, bool]:
    """The file's table, rebuilding its footer into `dst` when it has none; (table, was_rebuilt)."""
    try:
        return pq.read_table(path), False
    except Exception:  # noqa: BLE001 - any unreadable footer is what this command is for
        pass
    from lerobot.datasets.feature_utils import get_hf_features_from_features

    hf = get_hf_features_from_features(features)
    per_row = {k: 1 if features[k]["dtype"] == "image" else int(np.prod(features[k]["shape"])) for k in hf}
    return rebuild_footer(path, dst, hf.arrow_schema, per_row), True


def _complete_episodes(table: pa.Table) -> list[tuple[int, int, int]]:
    """(episode_index, first row, length) of each episode whose frames are 0..n-1 in order."""
    eps = table.column("episode_index").to_numpy()
    frames = table.column("frame_index").to_numpy()
    out = []
    start = 0
    for i in range(1, len(eps) + 1):
        if i == len(eps) or eps[i] != eps[start]:
            n = i - start
            if np.array_equal(frames[start:i], np.arange(n)):
                out.append((int(eps[start]), start, n))
            start = i
    return out


def _video_files(root: Path, key: str) -> list[Path]:
    return sorted((root / "videos" / key).glob("chunk-*/file-*.mp4"))


def _place_videos(root: Path, keys: list[str], lengths: list[int], fps: int) -> tuple[list[dict], int]:
    """Per episode, where each camera's frames are: {key: (chunk, file, from_ts, to_ts)}; and how many of the
    episodes are covered by complete video files (episodes were appended to the files in order)."""
    from lerobot.datasets.video_utils import get_video_duration_in_s

    placed: list[dict] = [{} for _ in lengths]
    covered = len(lengths)
    for key in keys:
        files = _video_files(root, key)
        durations = []
        for f in files:
            try:
                durations.append(get_video_duration_in_s(f))
            except Exception:  # noqa: BLE001 - an unreadable (unfinished) video ends what can be recovered
                break
        fi, t = 0, 0.0
        for ep, n in enumerate(lengths):
            d = n / fps
            while fi < len(durations) and t + d > durations[fi] + 0.5 / fps:
                fi, t = fi + 1, 0.0
            if fi >= len(durations):
                covered = min(covered, ep)
                break
            chunk = int(files[fi].parent.name.split("-")[1])
            file = int(files[fi].stem.split("-")[1])
            placed[ep][key] = (chunk, file, t, t + d)
            t += d
    return placed[:covered], covered


def _write_view(root: Path, view: Path, info: dict, table: pa.Table, episodes, placed, video_keys) -> None:
    """A read-only LeRobotDataset folder over the recovered rows and the original videos."""
    (view / "meta" / "episodes" / "chunk-000").mkdir(parents=True)
    (view / "data" / "chunk-000").mkdir(parents=True)
    rows = np.concatenate([np.arange(s, s + n) for _, s, n in episodes])
    data = table.take(pa.array(rows))
    new_index = np.arange(len(rows))
    new_eps = np.concatenate([np.full(n, i) for i, (_, _, n) in enumerate(episodes)])
    data = data.set_column(data.schema.get_field_index("index"), "index", pa.array(new_index, type=pa.int64()))
    data = data.set_column(
        data.schema.get_field_index("episode_index"), "episode_index", pa.array(new_eps, type=pa.int64())
    )
    pq.write_table(data, view / "data" / "chunk-000" / "file-000.parquet")
    tasks = pq.read_table(root / "meta" / "tasks.parquet").to_pandas()
    task_names = {int(i): name for name, i in zip(tasks.index, tasks["task_index"], strict=True)}
    task_col = data.column("task_index").to_numpy()
    cols: dict[str, list] = {k: [] for k in (
        "episode_index", "tasks", "length", "data/chunk_index", "data/file_index", "dataset_from_index",
        "dataset_to_index", "meta/episodes/chunk_index", "meta/episodes/file_index",
    )}
    for key in video_keys:
        for part in ("chunk_index", "file_index", "from_timestamp", "to_timestamp"):
            cols[f"videos/{key}/{part}"] = []
    start = 0
    for i, (_, _, n) in enumerate(episodes):
        cols["episode_index"].append(i)
        cols["tasks"].append(sorted({task_names[int(t)] for t in task_col[start : start + n]}))
        cols["length"].append(n)
        for k, v in (("data/chunk_index", 0), ("data/file_index", 0), ("meta/episodes/chunk_index", 0),
                     ("meta/episodes/file_index", 0), ("dataset_from_index", start), ("dataset_to_index", start + n)):
            cols[k].append(v)
        for key in video_keys:
            chunk, file, t0, t1 = placed[i][key]
            for part, v in zip(("chunk_index", "file_index", "from_timestamp", "to_timestamp"), (chunk, file, t0, t1),
                               strict=True):
                cols[f"videos/{key}/{part}"].append(v)
        start += n
    pq.write_table(pa.table(cols), view / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    shutil.copy2(root / "meta" / "tasks.parquet", view / "meta" / "tasks.parquet")
    try:  # may be cut short by the kill (it is rewritten after every episode); the new dataset gets its own
        json.loads((root / "meta" / "stats.json").read_text())
        shutil.copy2(root / "meta" / "stats.json", view / "meta" / "stats.json")
    except (OSError, ValueError):
        pass
    view_info = {**info, "total_episodes": len(episodes), "total_frames": len(rows),
                 "splits": {"train": f"0:{len(episodes)}"}}
    (view / "meta" / "info.json").write_text(json.dumps(view_info, indent=4))
    for key in video_keys:
        (view / "videos").mkdir(exist_ok=True)
        (view / "videos" / key).symlink_to((root / "videos" / key).resolve(), target_is_directory=True)


def _frame(item: dict, features: dict) -> dict:
    """A dataset item (decoded) as LeRobot's add_frame takes it: arrays in the features' dtype and layout."""
    frame = {}
    for key, ft in features.items():
        if key in ("timestamp", "frame_index", "episode_index", "index", "task_index") or key not in item:
            continue
        value = item[key].numpy() if hasattr(item[key], "numpy") else np.asarray(item[key])
        if ft["dtype"] in ("image", "video"):
            if (ft.get("info") or {}).get("is_depth_map"):
                value = np.rint(value).clip(0, np.iinfo(np.uint16).max).astype(np.uint16)  # decoded mm → raw
            else:
                value = (np.clip(value, 0.0, 1.0) * 255.0).round().astype(np.uint8)
            if value.ndim == 3 and value.shape[0] in (1, 3) and tuple(ft["shape"])[-1] == value.shape[0]:
                value = np.moveaxis(value, 0, -1)  # (C, H, W) → the stored (H, W, C)
        else:
            value = value.astype(ft["dtype"]).reshape(ft["shape"])
        frame[key] = value
    frame["task"] = item["task"]
    return frame


def salvage(root: str | Path, out: str | Path | None = None) -> dict:
    """Recover `root`'s finished episodes into `out` (default `<root>_salvaged`); returns a summary."""
    from lerobot.datasets import LeRobotDataset

    root = Path(root)
    out = Path(out) if out is not None else root.with_name(root.name + "_salvaged")
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise SalvageError(f"{root} has no meta/info.json: it is not a LeRobotDataset folder.")
    if out.exists():
        raise SalvageError(f"{out} already exists; pass --out with a new folder.")
    info = json.loads(info_path.read_text())
    features = _features(info)
    video_keys = [k for k, ft in features.items() if ft["dtype"] == "video"]
    claimed = int(info.get("total_episodes", 0))
    with tempfile.TemporaryDirectory(prefix="salvage_", dir=out.parent if out.parent.exists() else None) as tmp:
        tmp = Path(tmp)
        tables, rebuilt = [], []
        for i, path in enumerate(sorted(root.glob("data/chunk-*/file-*.parquet"))):
            try:
                table, was_rebuilt = _read_or_rebuild(path, tmp / f"data_{i}.parquet", features)
            except FooterRebuildError as exc:
                logger.warning("%s: nothing recoverable (%s)", path, exc)
                continue
            tables.append(table)
            if was_rebuilt:
                rebuilt.append(str(path.relative_to(root)))
        if not tables:
            raise SalvageError(f"{root}: no data file holds a complete episode; nothing can be recovered.")
        table = pa.concat_tables(tables)
        episodes = _complete_episodes(table)
        placed, covered = _place_videos(root, video_keys, [n for *_, n in episodes], int(info["fps"]))
        dropped_for_video = [e for e, *_ in episodes[covered:]]
        episodes = episodes[:covered]
        if not episodes:
            raise SalvageError(f"{root}: no episode has both its data and complete videos; nothing to recover.")
        view = tmp / "view"
        _write_view(root, view, info, table, episodes, placed, video_keys)
        source = LeRobotDataset("local/salvaged_view", root=view)
        target = LeRobotDataset.create(
            repo_id="local/" + out.name, fps=int(info["fps"]), features=info["features"], root=out,
            robot_type=info.get("robot_type"), use_videos=bool(video_keys),
        )
        try:
            for ep in range(source.num_episodes):
                start = int(source.meta.episodes[ep]["dataset_from_index"])
                for idx in range(start, int(source.meta.episodes[ep]["dataset_to_index"])):
                    target.add_frame(_frame(source[idx], features))
                target.save_episode()
        finally:
            target.finalize()
    return {
        "source": str(root), "out": str(out), "claimed_episodes": claimed, "recovered_episodes": len(episodes),
        "recovered_frames": int(sum(n for *_, n in episodes)), "rebuilt_files": rebuilt,
        "dropped_without_video": dropped_for_video,
    }


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "lerobot-focal-salvage-dataset")
    parser.add_argument("root", type=Path, help="the damaged LeRobotDataset folder (left unchanged)")
    parser.add_argument("--out", type=Path, default=None, help="new folder for the recovered dataset "
                        "(default: <root>_salvaged)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    try:
        summary = salvage(args.root, args.out)
    except SalvageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(
        f"recovered {summary['recovered_episodes']} episode(s), {summary['recovered_frames']} frames "
        f"(info.json claimed {summary['claimed_episodes']}) into {summary['out']}"
    )
    if summary["rebuilt_files"]:
        print(f"rebuilt the footer of {', '.join(summary['rebuilt_files'])}")
    if summary["dropped_without_video"]:
        print(f"dropped episode(s) {summary['dropped_without_video']}: their video was not complete")
    print(f"open it with --dataset.root={summary['out']} (repo id: local/{Path(summary['out']).name})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
