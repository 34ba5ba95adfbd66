"""Expert demonstrations for the grid: one training and one held-out LeRobotDataset per task, made once.

Both come from `lerobot-focal-collect` (MetaWorld's scripted experts; full-length episodes kept when successful
on ≥ 5 steps, as DP3 collects them). One pair per observation type a method of the grid reads. Training
demos use seeds from the preset's ``demo_seed`` (`grid_presets.DEMO_SEED` unless overridden), never those of
LeRobot's periodic evaluation; held-out episodes use seeds far from both (``HELDOUT_SEED``) so the open-loop
metrics see unseen object placements. Collection resumes, so a grid interrupted while collecting completes the
datasets on its next run.
Runs on a cluster read these paths: put ``--work`` on a filesystem every node sees.
"""

from __future__ import annotations

import fcntl
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from .grid_presets import DEMO_SEED, GridPreset
from .processes import run_logged
from .seeds import HELDOUT_SEED, demo_seed_of

#: Names the envs' point-cloud recipe in the folder of cached point-cloud demos. Change it with the recipe (crop
#: box, table crop, point count), so that demos cached by an earlier version are never trained on beside clouds
#: from today's evaluation env. "tablefree-sites": the table top and its rim are cropped away, and the clouds
#: hold the sites OpenGL draws (MetaWorld's goal marker among them). "-moved-welds": bodies welded to the world
#: that a reset moves (basketball's hoop, disassemble's peg) are drawn where this episode put them, not where
#: the env's first episode did (demos 2-10 of those tasks had them stale).
CLOUD_RECIPE = "tablefree-sites-moved-welds"


@dataclass(frozen=True)
class TaskData:
    task: str
    train_root: Path
    train_repo_id: str
    heldout_root: Path
    heldout_repo_id: str
    demo_seed: int = DEMO_SEED  # first reset seed of the training demos


def obs_types(preset: GridPreset, obs_type: str | None = None) -> str:
    """What the collector records for a method's observations (the state always). Camera methods get no object
    poses: what they know of the objects comes through the camera."""
    obs_type = obs_type or preset.obs_type
    types = [obs_type if obs_type in ("state", "pointcloud") else "pixels"]
    if preset.env_state and types[0] != "pixels":
        types.append("env_state")
    return ",".join(types)


def task_data(work: Path, task: str, preset: GridPreset, obs_type: str | None = None, seed: int = 0) -> TaskData:
    """Where a run of training seed ``seed`` finds its demos. With ``demos_per_seed`` each seed's training set is
    named by its first demo seed (``train-demos<first>``), so two seeds, or two presets with other demo seeds,
    never read each other's demos; the held-out set is shared."""
    obs_type = obs_type or preset.obs_type
    base = work / "data" / preset.data_folder / task
    if obs_type != preset.obs_type:
        base = base / (f"{obs_type}-{CLOUD_RECIPE}" if obs_type == "pointcloud" else obs_type)
    first = demo_seed_of(preset, seed)
    train, repo = (("train", f"local/{task}_train") if not preset.demos_per_seed
                   else (f"train-demos{first}", f"local/{task}_train_demos{first}"))
    return TaskData(task, base / train, repo, base / "heldout", f"local/{task}_heldout", first)


def _collect(root: Path, repo_id: str, task: str, episodes: int, seed: int, preset: GridPreset, log: Path,
             obs_type: str | None) -> None:
    cmd = [
        sys.executable, "-m", "lerobot_focal.datasets.making.collect",
        "--root", str(root), "--repo_id", repo_id, "--tasks", task, "--episodes", str(episodes),
        "--obs_types", obs_types(preset, obs_type), "--max_steps", str(preset.episode_length), "--seed", str(seed),
        "--image_size", str(preset.image_size), "--num_points", str(preset.train_points),
        "--table_clearance", str(preset.table_clearance).lower(),
    ]
    log.parent.mkdir(parents=True, exist_ok=True)
    run_logged(cmd, log, dict(os.environ), f"collecting {task} demos")
    have = json.loads((root / "meta" / "info.json").read_text())["total_episodes"]
    if have < episodes:
        raise RuntimeError(
            f"the scripted expert solved only {have}/{episodes} {task} episodes within {preset.episode_length} steps "
            f"(see {log}); raise --episode-length or drop the task"
        )


def ensure_task_data(work: Path, task: str, preset: GridPreset, obs_type: str | None = None,
                     seed: int = 0) -> TaskData:
    """Collect (or complete) the task's training and held-out datasets under ``work``."""
    return collect_task_data(task_data(work, task, preset, obs_type, seed), preset, obs_type, work / "logs")


def collect_task_data(data: TaskData, preset: GridPreset, obs_type: str | None, log_dir: Path) -> TaskData:
    """Called by every run before it trains: the first run of a (task, obs type) collects, later ones find the
    data complete; a lock file keeps concurrent runs from writing the same dataset twice."""
    name = f"{preset.data_folder}_{data.task}_{obs_type or preset.obs_type}"
    if preset.demos_per_seed:
        name += f"_demos{data.demo_seed}"
    log = log_dir / f"collect_{name}.log"
    log_dir.mkdir(parents=True, exist_ok=True)
    with open(log_dir / f".collect_{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        for root, repo_id, episodes, seed in ((data.train_root, data.train_repo_id, preset.demos, data.demo_seed),
                                              (data.heldout_root, data.heldout_repo_id, preset.heldout_demos,
                                               HELDOUT_SEED)):
            if _complete(root, episodes):
                continue
            _collect(root, repo_id, data.task, episodes, seed, preset, log, obs_type)
    return data


def _complete(root: Path, episodes: int) -> bool:
    info = root / "meta" / "info.json"
    return info.exists() and json.loads(info.read_text())["total_episodes"] >= episodes
