"""Adroit: a small Minari dataset made here -> replayed import into a LeRobotDataset (real process)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # the import command (~20 s), an optional route into the benchmark's datasets

minari = pytest.importorskip("minari")
pytest.importorskip("gymnasium_robotics")

REPO = Path(__file__).resolve().parents[2]
DATASET_ID = "adroit/door/random-v0"
STEPS = 20


def _make_minari_dataset(minari_root: Path) -> list[np.ndarray]:
    """Three random-action door episodes; the third records a wrong reset seed (its replay must diverge)."""
    import gymnasium as gym
    import gymnasium_robotics
    from minari.data_collector import EpisodeBuffer

    gym.register_envs(gymnasium_robotics)
    os.environ["MINARI_DATASETS_PATH"] = str(minari_root)
    env = gym.make("AdroitHandDoor-v1", max_episode_steps=STEPS)
    env.action_space.seed(0)
    buffers, all_actions = [], []
    for ep, (seed, recorded_seed) in enumerate([(10, 10), (11, 11), (12, 99)]):
        obs, _ = env.reset(seed=seed)
        observations, actions, rewards, terms, truncs = [obs], [], [], [], []
        for _ in range(STEPS):
            action = env.action_space.sample()
            obs, reward, terminated, truncated, _ = env.step(action)
            observations.append(obs)
            actions.append(action)
            rewards.append(reward)
            terms.append(terminated)
            truncs.append(truncated)
        all_actions.append(np.array(actions))
        buffers.append(
            EpisodeBuffer(
                id=ep, seed=recorded_seed, observations=np.array(observations), actions=np.array(actions),
                rewards=np.array(rewards), terminations=np.array(terms), truncations=np.array(truncs), infos={},
            )
        )
    minari.create_dataset_from_buffers(
        dataset_id=DATASET_ID, buffer=buffers, env=env, algorithm_name="random", author="focal tests",
        author_email="tests@example.invalid", code_permalink="n/a", data_format="arrow",
    )
    env.close()
    return all_actions


def _import(minari_root, root, *extra):
    cmd = [sys.executable, "-m", "lerobot_focal.datasets.making.minari_import", "--dataset_id", DATASET_ID,
           "--root", str(root), "--minari_root", str(minari_root), *extra]
    result = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result.stdout + result.stderr


def test_minari_import_replays_and_filters(tmp_path):
    from lerobot.datasets import LeRobotDataset

    minari_root = tmp_path / "minari"
    actions = _make_minari_dataset(minari_root)

    out = _import(minari_root, tmp_path / "all", "--all_episodes")
    assert "door: 2 of 3 episodes written (0 unsuccessful, 1 diverged" in out
    ds = LeRobotDataset("local/focal_adroit", root=tmp_path / "all")
    assert ds.num_episodes == 2 and len(ds) == 2 * STEPS
    assert list(ds.meta.episodes["tasks"][0]) == ["Undo the latch and swing the door open."]
    item = ds[0]
    assert item["observation.pointcloud"].shape == (512, 3) and item["observation.state"].shape == (24,)
    for ep in range(2):
        stored = np.stack([ds.hf_dataset[ep * STEPS + t]["action"].numpy() for t in range(STEPS)])
        np.testing.assert_allclose(stored, actions[ep], atol=1e-6)

    # Default: only episodes whose replay succeeds; random actions never open the door (in-process this time).
    from lerobot_focal.datasets.making.minari_import import ImportConfig, import_minari

    summary = import_minari(ImportConfig(dataset_id=DATASET_ID, root=tmp_path / "ok", minari_root=str(minari_root)))
    assert summary == {"task": "door", "episodes_in": 3, "written": 0, "failed": 2, "diverged": 1, "no_seed": 0}
