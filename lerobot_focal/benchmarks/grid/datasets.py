"""Expert demonstrations for the grid: one training and one held-out LeRobotDataset per task, made once.

Both come from `lerobot-focal-collect` (MetaWorld's scripted experts, successful episodes only). Held-out
episodes use seeds far from the training ones (``HELDOUT_SEED``) so the open-loop metrics see unseen object
placements. Collection resumes, so a grid interrupted while collecting completes the datasets on its next run.
Runs on a cluster read these paths: put ``--work`` on a filesystem every node sees.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from .presets import GridPreset

HELDOUT_SEED = 100_000


@dataclass(frozen=True)
class TaskData:
    task: str
    train_root: Path
    train_repo_id: str
    heldout_root: Path
    heldout_repo_id: str


def obs_types(preset: GridPreset) -> str:
    types = [preset.obs_type if preset.obs_type in ("state", "pointcloud") else "pixels"]
    if preset.env_state:
        types.append("env_state")
    return ",".join(types)


def task_data(work: Path, task: str, preset: GridPreset) -> TaskData:
    base = work / "data" / preset.name / task
    return TaskData(task, base / "train", f"local/{task}_train", base / "heldout", f"local/{task}_heldout")


def _collect(root: Path, repo_id: str, task: str, episodes: int, seed: int, preset: GridPreset, log: Path) -> None:
    cmd = [
        sys.executable, "-m", "lerobot_focal.datasets.collect",
        "--root", str(root), "--repo_id", repo_id, "--tasks", task, "--episodes", str(episodes),
        "--obs_types", obs_types(preset), "--max_steps", str(preset.episode_length), "--seed", str(seed),
    ]
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a") as f:
        rc = subprocess.call(cmd, stdout=f, stderr=subprocess.STDOUT)
    if rc != 0:
        raise RuntimeError(f"collecting {task} demos failed (exit {rc}); see {log}")
    have = json.loads((root / "meta" / "info.json").read_text())["total_episodes"]
    if have < episodes:
        raise RuntimeError(
            f"the scripted expert solved only {have}/{episodes} {task} episodes within {preset.episode_length} steps "
            f"(see {log}); raise --episode-length or drop the task"
        )


def ensure_task_data(work: Path, task: str, preset: GridPreset) -> TaskData:
    data = task_data(work, task, preset)
    log = work / "logs" / f"collect_{preset.name}_{task}.log"
    _collect(data.train_root, data.train_repo_id, task, preset.demos, 0, preset, log)
    _collect(data.heldout_root, data.heldout_repo_id, task, preset.heldout_demos, HELDOUT_SEED, preset, log)
    return data
