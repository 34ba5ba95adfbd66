"""lerobot-focal-collect as a real process: MetaWorld experts -> LeRobotDataset on disk; interrupt + resume."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("metaworld")

REPO = Path(__file__).resolve().parents[2]
REPO_ID = "local/focal_metaworld"


def _collect(*args, **popen):
    cmd = [sys.executable, "-m", "lerobot_focal.datasets.making.collect", *args]
    return subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **popen)


def _load(root):
    from lerobot.datasets import LeRobotDataset

    return LeRobotDataset(REPO_ID, root=root)


def _replay_success_steps(episode_actions, seed):
    """Steps on which MetaWorld reports success when the stored actions are replayed from the episode's seed."""
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    env = FocalMetaworldEnvConfig(task="reach", obs_type="state").make_single_env()
    try:
        env.reset(seed=seed)
        steps = 0
        for action in episode_actions:
            *_, info = env.step(np.asarray(action, dtype=np.float32))
            steps += bool(info["is_success"])
        return steps
    finally:
        env.close()


@pytest.mark.subprocess
def test_collect_interrupt_then_resume(tmp_path):
    root = tmp_path / "mw"
    args = ["--root", str(root), "--tasks", "reach", "--episodes", "3"]
    proc = _collect(*args)
    state = root / "focal_collect_state.json"
    deadline = time.time() + 240
    # Interrupt while the 2nd episode is being rolled out (the 1st is saved by then).
    while time.time() < deadline and proc.poll() is None:
        if state.exists() and json.loads(state.read_text()).get("reach-v3", {}).get("attempts", 0) >= 1:
            time.sleep(1.0)
            break
        time.sleep(0.2)
    assert proc.poll() is None, proc.stdout.read()
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, out
    assert "Run the same command again" in out

    partial = _load(root)
    assert 1 <= partial.num_episodes < 3
    first = partial[0]
    assert first["observation.pointcloud"].shape == (512, 3) and first["observation.state"].shape == (9,)

    proc = _collect(*args)
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, out
    assert "reach-v3: 3 episodes" in out
    ds = _load(root)
    assert ds.num_episodes == 3
    lengths = list(ds.meta.episodes["length"])
    assert lengths == [200, 200, 200]  # DP3's collection: whole episodes, post-success behaviour included
    assert set(t for tasks in ds.meta.episodes["tasks"] for t in tasks) == {"Reach a goal position"}
    # Point-cloud stats are per xyz channel, as the policy's normaliser expects.
    assert np.asarray(ds.meta.stats["observation.pointcloud"]["mean"]).shape == (3,)
    # Every stored episode is a success on ≥ 5 steps: replaying its actions from its seed shows it (no failures
    # on reach, so episode i used seed i).
    assert json.loads((root / "focal_collect_state.json").read_text())["reach-v3"]["failures"] == 0
    for ep in range(3):
        start = int(ds.meta.episodes["dataset_from_index"][ep])
        actions = [ds.hf_dataset[start + i]["action"] for i in range(lengths[ep])]
        assert _replay_success_steps(actions, seed=ep) >= 5


@pytest.mark.subprocess
def test_collect_until_success_stops_at_the_first_success(tmp_path):
    root = tmp_path / "mw_short"
    proc = _collect("--root", str(root), "--tasks", "reach", "--episodes", "2", "--obs_types", "state",
                    "--until", "success")
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, out
    ds = _load(root)
    lengths = list(ds.meta.episodes["length"])
    assert len(lengths) == 2 and all(0 < n < 200 for n in lengths)  # reach's expert succeeds early
    for ep in range(2):
        start = int(ds.meta.episodes["dataset_from_index"][ep])
        actions = [ds.hf_dataset[start + i]["action"] for i in range(lengths[ep])]
        assert _replay_success_steps(actions, seed=ep) == 1  # the episode ends on its first success


@pytest.mark.subprocess
def test_collect_drops_failed_episodes(tmp_path):
    root = tmp_path / "mw_fail"
    proc = _collect("--root", str(root), "--tasks", "pick-place", "--episodes", "1", "--max_steps", "5",
                    "--max_attempts", "2", "--obs_types", "state,pixels")
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, out
    assert "pick-place-v3: 0 episodes, 2 attempts (2 failed)" in out
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 0
    assert "observation.image" in info["features"] and "observation.pointcloud" not in info["features"]


def test_collect_rejects_bad_arguments(tmp_path, capsys):
    from lerobot_focal.datasets.making.collect import parse_args

    with pytest.raises(SystemExit) as exc:
        parse_args(["--root", str(tmp_path / "x"), "--obs_types", "depth"])
    assert exc.value.code == 2 and "--obs_types" in capsys.readouterr().err
    cfg = parse_args(["--root", str(tmp_path / "x"), "--tasks", "easy,reach", "--obs_types", "pixels,state"])
    assert cfg.episodes == 10 and cfg.obs_types == ("pixels", "state") and cfg.attempts_limit == 30
