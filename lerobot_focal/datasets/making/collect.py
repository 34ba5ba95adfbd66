"""``lerobot-focal-collect``: MetaWorld scripted-expert demonstrations -> a local LeRobotDataset.

    python -m lerobot_focal.datasets.making.collect --root data/mw_reach --tasks reach --episodes 10
    python -m lerobot_focal.datasets.making.collect --root data/mw_easy --tasks easy --obs_types pointcloud,pixels

* ``--tasks``: MetaWorld v3 task names and/or difficulty groups (easy, medium, hard, very_hard), comma-separated.
* Each task gets ``--episodes`` *successful* episodes (default 10). Attempts use seeds ``seed, seed+1, ...``;
  failed attempts are dropped, and a task gives up after ``--max_attempts`` (default 3 x episodes).
* ``--until full`` (default) runs every episode for the whole ``--max_steps`` and keeps it when MetaWorld's
  success signal held on at least ``--min_success_steps`` steps (5), as DP3 collects the data the paper trains
  on: 10 demos are then 2000 frames, post-success behaviour included. ``--until success`` stops each episode at
  its first success (about 4x fewer frames; the behaviour of earlier versions).
* ``--obs_types``: any of state, pointcloud, pixels, env_state (comma-separated). The dataset always has
  ``action`` (4,) and ``observation.state`` (9,); pointcloud adds ``observation.pointcloud`` (512, 3), pixels adds
  ``observation.image`` (H, W, 3) and env_state adds MetaWorld's 39-d ``observation.environment_state``: the
  keys ``focal_metaworld`` envs deliver to the policy at evaluation (``--env.env_state=true`` for the last).
* Interruption (Ctrl-C, SIGTERM): the episode in progress is dropped, the writer is finalized, and what was
  saved is a valid dataset. Running the same command again resumes: it counts the episodes each task already
  has and only collects the rest (seeds already tried are not reused).
* A hard kill (SIGKILL, out of memory, power loss) loses at most the episode in flight: every saved episode is
  closed on disk and committed (`lerobot_focal.datasets.making.commit_log`), and the rerun first rolls the folder
  back to the last commit, then continues. The price is one data and one metadata parquet file per episode.
* ``--push_to_hub`` uploads the finished dataset (needs a Hub login; off by default).
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_focal.console import doc_parser
from lerobot_focal.constants import OBS_POINTCLOUD
from lerobot_focal.datasets.making import commit_log
from lerobot_focal.envs.focal_metaworld import DEFAULT_TABLE_CLEARANCE

STATE_FILE = "focal_collect_state.json"
VALID_OBS = ("state", "pointcloud", "pixels", "env_state")
#: Without --max_attempts, a task gets this many reset seeds per wanted episode before collection gives up.
ATTEMPTS_PER_EPISODE = 3


@dataclass
class CollectConfig:
    root: Path
    tasks: list[str]
    repo_id: str = "local/focal_metaworld"
    episodes: int = 10
    obs_types: tuple[str, ...] = ("pointcloud",)
    max_steps: int = 200
    max_attempts: int | None = None
    seed: int = 0
    image_size: int = 128
    num_points: int = 512
    # Point clouds: the table top is cropped this far above its surface (m); None keeps the table (DP3's crop
    # keeps part of it). The env's default otherwise.
    table_clearance: float | None = DEFAULT_TABLE_CLEARANCE
    push_to_hub: bool = False
    until: str = "full"  # "full": whole episodes, kept when successful ≥ min_success_steps; "success": stop at it
    min_success_steps: int = 5

    @property
    def attempts_limit(self) -> int:
        return self.max_attempts if self.max_attempts is not None else ATTEMPTS_PER_EPISODE * self.episodes


def dataset_features(cfg: CollectConfig) -> dict[str, dict]:
    from lerobot_focal.envs.focal_metaworld import (
        METAWORLD_ACTION_DIM,
        METAWORLD_ENV_STATE_DIM,
        METAWORLD_STATE_DIM,
    )

    features: dict[str, dict] = {
        "action": {"dtype": "float32", "shape": (METAWORLD_ACTION_DIM,), "names": ["dx", "dy", "dz", "gripper"]},
        "observation.state": {
            "dtype": "float32",
            "shape": (METAWORLD_STATE_DIM,),
            "names": [f"{part}_{axis}" for part in ("hand", "right_pad", "left_pad") for axis in "xyz"],
        },
    }
    if "pointcloud" in cfg.obs_types:
        features[OBS_POINTCLOUD] = {
            "dtype": "float32", "shape": (cfg.num_points, 3), "names": ["points", "xyz"],
        }
    if "env_state" in cfg.obs_types:
        features["observation.environment_state"] = {
            "dtype": "float32", "shape": (METAWORLD_ENV_STATE_DIM,), "names": None,
        }
    if "pixels" in cfg.obs_types:
        features["observation.image"] = {
            "dtype": "image", "shape": (cfg.image_size, cfg.image_size, 3), "names": ["height", "width", "channels"],
        }
    return features


def _env_obs_type(obs_types: tuple[str, ...]) -> str:
    if "pointcloud" in obs_types:
        return "pointcloud"  # + a render() per step when pixels are asked for too
    if "pixels" in obs_types:
        return "pixels_agent_pos"
    return "state"


class _Interrupted(Exception):
    pass


class _GracefulStop:
    """Turn SIGINT/SIGTERM into an exception raised between env steps (never inside the dataset writer)."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: dict[int, object] = {}

    def __enter__(self) -> _GracefulStop:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def _handler(self, signum, frame) -> None:
        self.requested = True

    def check(self) -> None:
        if self.requested:
            raise _Interrupted

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def _load_state(root: Path) -> dict:
    path = root / STATE_FILE
    return json.loads(path.read_text()) if path.exists() else {}


def _save_state(root: Path, state: dict) -> None:
    tmp = root / (STATE_FILE + ".tmp")
    tmp.write_text(json.dumps(state, indent=1, sort_keys=True))
    tmp.replace(root / STATE_FILE)


def _episodes_per_task(root: Path, repo_id: str) -> Counter:
    """Successful episodes already in the dataset, per task description (the dataset is the source of truth)."""
    from lerobot.datasets import LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata(repo_id, root=root)
    counts: Counter = Counter()
    if meta.total_episodes and meta.episodes is not None:
        for tasks in meta.episodes["tasks"]:
            for task in tasks:
                counts[task] += 1
    return counts


def _unreadable_parquet_files(root: Path) -> list[str]:
    """Parquet files of the dataset that cannot be opened (e.g. no footer: their writer was killed)."""
    import pyarrow.parquet as pq

    bad = []
    for path in sorted([*root.glob("data/**/*.parquet"), *root.glob("meta/**/*.parquet")]):
        try:
            pq.ParquetFile(path).metadata  # noqa: B018 - reading the footer is the check
        except Exception as exc:  # noqa: BLE001 - any failure to read the footer means the same to the user
            bad.append(f"{path.relative_to(root)} ({exc})")
    return bad


def _open_dataset(cfg: CollectConfig, features: dict, fps: int):
    from lerobot.datasets import LeRobotDataset

    info = cfg.root / "meta" / "info.json"
    if info.exists():
        if commit_log.has_commit(cfg.root):
            changed = commit_log.rollback(cfg.root)
            if changed:
                logging.warning(
                    "%s: the previous run stopped while saving an episode (killed?); its unfinished files were "
                    "rolled back (%s). Continuing from the last saved episode.", cfg.root, ", ".join(changed),
                )
        else:
            bad = _unreadable_parquet_files(cfg.root)
            if bad:
                raise SystemExit(
                    f"{cfg.root} holds parquet files that cannot be read: {'; '.join(bad)}. A process writing this "
                    "dataset was killed before it closed them (this happens to datasets written by LeRobot's own "
                    "writer, or by lerobot-focal-collect before it committed each episode). Fix: try "
                    f"`lerobot-focal-salvage-dataset {cfg.root}` to recover the finished episodes into a new folder, "
                    "or delete the folder and collect again."
                )
        existing = json.loads(info.read_text())["features"]
        missing = sorted(set(features) - set(existing))
        if missing:
            raise SystemExit(
                f"{cfg.root} already holds a dataset without {missing}; collect other obs types into a new --root"
            )
        dataset = LeRobotDataset.resume(cfg.repo_id, root=cfg.root)
    else:
        if cfg.root.exists() and any(cfg.root.iterdir()):
            raise SystemExit(f"{cfg.root} exists and is not a LeRobotDataset; choose an empty or new --root")
        dataset = LeRobotDataset.create(
            repo_id=cfg.repo_id, fps=fps, features=features, root=cfg.root, use_videos=False,
            robot_type="sawyer", metadata_buffer_size=1,
        )
    commit_log.commit(cfg.root)  # every file is closed here: the state a kill rolls back to
    return dataset


def _save_durably(dataset, cfg: CollectConfig):
    """Save the buffered episode, close every file, commit; returns the dataset reopened for the next episode.

    LeRobot writes a parquet footer only when a file is closed, so an episode is safe from a kill only once
    its files are closed; resuming then starts new files for the next episode (closed files never change).
    """
    from lerobot.datasets import LeRobotDataset

    dataset.save_episode()
    dataset.finalize()
    commit_log.commit(cfg.root)
    return LeRobotDataset.resume(cfg.repo_id, root=cfg.root)


def rollout_expert(
    env,
    seed: int,
    max_steps: int,
    want_pixels: bool,
    stop: _GracefulStop | None = None,
    *,
    until: str = "success",
    min_success_steps: int = 1,
):
    """One scripted-expert episode; returns (frames, success). Frames hold the observation *before* each action.

    ``until="success"`` ends the episode at the first success (the env terminates there). ``until="full"`` runs
    all ``max_steps`` (ignoring the env's terminate-on-success) and counts the episode successful when the success
    signal was on for at least ``min_success_steps`` steps, DP3's rule for keeping a demonstration.
    """
    if until not in ("success", "full"):
        raise ValueError(f"until must be 'success' or 'full', got {until!r}")
    obs, _ = env.reset(seed=seed)
    frames = []
    success_steps = 0
    for _ in range(max_steps):
        if stop is not None:
            stop.check()
        action = env.expert_action()
        frame = {"observation.state": obs["agent_pos"], "action": action}
        if "pointcloud" in obs:
            frame[OBS_POINTCLOUD] = obs["pointcloud"]
        if "environment_state" in obs:
            frame["observation.environment_state"] = obs["environment_state"]
        if want_pixels:
            frame["observation.image"] = obs["pixels"] if "pixels" in obs else np.ascontiguousarray(env.render())
        frames.append(frame)
        obs, _, terminated, truncated, info = env.step(action)
        success_steps += bool(info["is_success"])
        if until == "success" and (terminated or truncated):
            break
        if until == "full" and truncated:
            break
    return frames, success_steps >= (min_success_steps if until == "full" else 1)


def collect(cfg: CollectConfig) -> dict:
    """Collect (or complete) the dataset; returns a summary dict. Raises KeyboardInterrupt after a clean stop."""
    from tqdm import tqdm

    from lerobot_focal.envs.focal_metaworld import TASK_DESCRIPTIONS, FocalMetaworldEnvConfig

    cfg.root = Path(cfg.root)
    env_cfg = FocalMetaworldEnvConfig(
        task=",".join(cfg.tasks), obs_type=_env_obs_type(cfg.obs_types), episode_length=cfg.max_steps,
        observation_width=cfg.image_size, observation_height=cfg.image_size, num_points=cfg.num_points,
        env_state="env_state" in cfg.obs_types, table_clearance=cfg.table_clearance,
    )
    tasks = list(dict.fromkeys(t for group in env_cfg.tasks_by_group.values() for t in group))
    features = dataset_features(cfg)
    dataset = _open_dataset(cfg, features, env_cfg.fps)
    has_info = cfg.root.joinpath("meta", "info.json").exists()
    done_counts = _episodes_per_task(cfg.root, cfg.repo_id) if has_info else Counter()
    state = _load_state(cfg.root)
    want_pixels = "pixels" in cfg.obs_types
    total_needed = sum(max(0, cfg.episodes - done_counts[TASK_DESCRIPTIONS[t]]) for t in tasks)
    summary: dict = {"tasks": {}, "root": str(cfg.root)}
    interrupted = False
    bar = tqdm(total=len(tasks) * cfg.episodes, initial=len(tasks) * cfg.episodes - total_needed, unit="episode")
    try:
        with _GracefulStop() as stop:
            for task in tasks:
                description = TASK_DESCRIPTIONS[task]
                task_state = state.setdefault(task, {"next_seed": cfg.seed, "attempts": 0, "failures": 0})
                have = done_counts[description]
                start = time.perf_counter()
                env = env_cfg.make_single_env(task) if have < cfg.episodes else None
                try:
                    while have < cfg.episodes and task_state["attempts"] < cfg.attempts_limit:
                        seed = task_state["next_seed"]
                        bar.set_postfix_str(f"{task} seed={seed} failures={task_state['failures']}")
                        frames, success = rollout_expert(
                            env, seed, cfg.max_steps, want_pixels, stop, until=cfg.until,
                            min_success_steps=cfg.min_success_steps,
                        )
                        # Advance the seed before writing: a crash mid-write skips a seed, never repeats one.
                        task_state["next_seed"] = seed + 1
                        task_state["attempts"] += 1
                        if not success:
                            task_state["failures"] += 1
                            _save_state(cfg.root, state)
                            continue
                        _save_state(cfg.root, state)
                        for frame in frames:
                            dataset.add_frame({**frame, "task": description})
                        dataset = _save_durably(dataset, cfg)
                        have += 1
                        bar.update(1)
                finally:
                    if env is not None:
                        env.close()
                summary["tasks"][task] = {
                    "episodes": have,
                    "attempts": task_state["attempts"],
                    "failures": task_state["failures"],
                    "seconds": round(time.perf_counter() - start, 2),
                }
                if have < cfg.episodes:
                    logging.warning(
                        "%s: only %d/%d successful episodes after %d attempts", task, have, cfg.episodes,
                        task_state["attempts"],
                    )
    except _Interrupted:
        interrupted = True
        if dataset.has_pending_frames():
            dataset.clear_episode_buffer()
    finally:
        bar.close()
        dataset.finalize()
        _save_state(cfg.root, state)
    summary["total_episodes"] = dataset.meta.total_episodes
    summary["interrupted"] = interrupted
    if interrupted:
        raise KeyboardInterrupt(f"collection interrupted; {summary['total_episodes']} episodes saved in {cfg.root}")
    if cfg.push_to_hub:
        # The dataset's own files only: not the collection's seed state or its commit record.
        dataset.push_to_hub(allow_patterns=["data/*", "meta/*"])
    return summary


def table_clearance_arg(text: str) -> float | None:
    """A command line's table clearance: a height ≥ 0 in metres, or 'none' (None: keep the table)."""
    if text.lower() == "none":
        return None
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"expected a height ≥ 0 in metres or 'none'; got {text!r}")
    return value


def parse_args(argv: list[str] | None = None) -> CollectConfig:
    parser = doc_parser(__doc__, "lerobot-focal-collect")
    parser.add_argument("--root", required=True, type=Path, help="local dataset directory (created or resumed)")
    parser.add_argument("--tasks", default="reach", help="tasks and/or groups, comma-separated (default: reach)")
    parser.add_argument("--repo_id", default="local/focal_metaworld")
    parser.add_argument("--episodes", type=int, default=10, help="successful episodes per task (default 10)")
    parser.add_argument("--obs_types", default="pointcloud", help=f"comma-separated subset of {VALID_OBS}")
    parser.add_argument("--max_steps", type=int, default=200, help="episode length limit (default 200)")
    parser.add_argument("--max_attempts", type=int, default=None, help="per task; default 3 x episodes")
    parser.add_argument("--seed", type=int, default=0, help="first reset seed of each task")
    parser.add_argument("--image_size", type=int, default=128)
    parser.add_argument("--num_points", type=int, default=512)
    parser.add_argument("--table_clearance", type=table_clearance_arg, default=DEFAULT_TABLE_CLEARANCE,
                        help="point clouds: crop the table top this far above its surface (m), or 'none' to keep "
                             f"the table (default {DEFAULT_TABLE_CLEARANCE})")
    parser.add_argument("--until", choices=("full", "success"), default="full",
                        help="full: run every episode to --max_steps and keep it when successful on at least "
                             "--min_success_steps steps (DP3's data); success: stop at the first success")
    parser.add_argument("--min_success_steps", type=int, default=5)
    parser.add_argument("--push_to_hub", action="store_true")
    args = parser.parse_args(argv)
    obs_types = tuple(dict.fromkeys(o.strip() for o in args.obs_types.split(",") if o.strip()))
    bad = [o for o in obs_types if o not in VALID_OBS]
    if bad or not obs_types:
        parser.error(f"--obs_types must be a comma-separated subset of {', '.join(VALID_OBS)}; got {args.obs_types!r}")
    if args.episodes <= 0:
        parser.error("--episodes must be positive")
    return CollectConfig(
        root=args.root, tasks=[t for t in args.tasks.split(",") if t.strip()], repo_id=args.repo_id,
        episodes=args.episodes, obs_types=obs_types, max_steps=args.max_steps, max_attempts=args.max_attempts,
        seed=args.seed, image_size=args.image_size, num_points=args.num_points, push_to_hub=args.push_to_hub,
        table_clearance=args.table_clearance,
        until=args.until, min_success_steps=args.min_success_steps,
    )


def _quiet_libraries() -> None:
    """Keep the terminal to one progress bar: no per-episode stats bars, no expert-gain warnings."""
    import warnings

    import datasets

    datasets.disable_progress_bars()
    warnings.filterwarnings("ignore", message="Constant\\(s\\) may be too high")


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    _quiet_libraries()
    cfg = parse_args(argv)
    try:
        summary = collect(cfg)
    except KeyboardInterrupt as exc:
        print(f"\n{exc}. Run the same command again to complete it.", flush=True)
        return 130
    for task, row in summary["tasks"].items():
        print(
            f"{task}: {row['episodes']} episodes, {row['attempts']} attempts ({row['failures']} failed), "
            f"{row['seconds']} s"
        )
    print(f"dataset: {summary['root']} ({summary['total_episodes']} episodes)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
