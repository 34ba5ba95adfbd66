"""One NaN or inf in a LeRobotDataset stops `lerobot-train --policy.type=focal` before training, naming the
feature, the dimension and the episode/frame that hold it (instead of training to exit 0 with a dead input,
or failing at step 1 with a count of NaN values that names neither)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_focal.datasets.making.synthetic import SyntheticSpec, episode_arrays, features

pytestmark = pytest.mark.subprocess  # lerobot-train on a poisoned dataset

BIN = Path(sys.executable).parent


def _write(root: Path, key: str, episode: int, frame: int, dim: int, value: float) -> None:
    """The synthetic dataset with one poisoned value, written through LeRobot's own writer (stats included)."""
    spec = SyntheticSpec(num_episodes=3, episode_length=16, num_points=16)
    ds = LeRobotDataset.create(repo_id="local/poisoned", fps=spec.fps, features=features(spec), root=root,
                               use_videos=False)
    for ep in range(spec.num_episodes):
        arrays = episode_arrays(spec, ep)
        if ep == episode:
            arrays[key][frame, dim] = value
        for i in range(spec.episode_length):
            ds.add_frame({**{k: v[i] for k, v in arrays.items()}, "task": "reach"})
        ds.save_episode()
    ds.finalize()


@pytest.mark.parametrize(
    ("key", "episode", "frame", "dim", "value", "stats"),
    [
        pytest.param("observation.state", 1, 5, 3, float("inf"), "dimension 3: max=inf, mean=nan, std=nan",
                     id="inf_state", marks=pytest.mark.slow),  # a second lerobot-train (~15 s): the slow tier
        pytest.param("action", 0, 7, 2, float("nan"), "dimension 2: min=nan, max=nan, mean=nan, std=nan",
                     id="nan_action"),
    ],
)
def test_nonfinite_value_is_named_before_training(key, episode, frame, dim, value, stats, tmp_path):
    root = tmp_path / "dataset"
    _write(root, key, episode, frame, dim, value)
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    proc = subprocess.run(
        [
            str(BIN / "lerobot-train"), "--policy.type=focal", "--policy.down_dims=[16,32]", "--policy.device=cpu",
            "--policy.push_to_hub=false", "--dataset.repo_id=local/poisoned", f"--dataset.root={root}",
            f"--output_dir={tmp_path / 'run'}", "--steps=2", "--batch_size=2", "--num_workers=0",
        ],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode != 0, "training ran on poisoned statistics"
    err = proc.stderr
    assert f"normalisation statistics are not finite for '{key}' ({stats})" in err, err[-3000:]
    assert f"episode {episode} frame {frame} has {key}[{dim}] = {value}" in err
    fix = (f'--repo_id local/poisoned --root {root} --operation.type delete_episodes '
           f'--operation.episode_indices "[{episode}]"')
    assert f"lerobot-edit-dataset {fix}" in err
    assert not (tmp_path / "run" / "checkpoints").exists()
