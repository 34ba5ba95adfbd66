"""Collect -> lerobot-train (focal) -> lerobot-eval on focal_metaworld, all as real CLI processes."""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("metaworld")

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def _run(cmd, timeout, **kw):
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    result = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout, **kw)
    assert result.returncode == 0, f"{cmd[0]} failed:\n{result.stdout[-4000:]}\n{result.stderr[-4000:]}"
    return result.stdout + result.stderr


def _train(dataset_root, out_dir, steps=6, repo_id="local/focal_metaworld"):
    assert shutil.which("lerobot-train", path=str(BIN)), "lerobot-train not installed in this venv"
    _run(
        [
            str(BIN / "lerobot-train"), "--policy.type=focal", f"--dataset.repo_id={repo_id}",
            f"--dataset.root={dataset_root}", "--policy.down_dims=[32,64,128]", f"--steps={steps}",
            "--batch_size=4", "--policy.push_to_hub=false", "--wandb.enable=false", "--num_workers=0",
            f"--output_dir={out_dir}", f"--save_freq={steps}", "--log_freq=1", "--policy.device=cpu",
        ],
        timeout=900,
    )
    ckpt = out_dir / "checkpoints" / "last" / "pretrained_model"
    assert (ckpt / "model.safetensors").exists()
    return ckpt


def _eval(ckpt, env_args, out_dir, metrics):
    out = _run(
        [
            str(BIN / "lerobot-eval"), f"--policy.path={ckpt}", *env_args, "--eval.n_episodes=2",
            "--eval.batch_size=1", "--policy.device=cpu", f"--output_dir={out_dir}", f"--env.metrics_path={metrics}",
        ],
        timeout=900,
    )
    info = json.loads((out_dir / "eval_info.json").read_text())
    episodes = [json.loads(line) for line in metrics.read_text().splitlines()]
    return out, info, episodes


@pytest.mark.slow
def test_collect_train_eval_metaworld(tmp_path):
    data = tmp_path / "data"
    _run([sys.executable, "-m", "lerobot_focal.datasets.making.collect", "--root", str(data), "--tasks", "reach",
          "--episodes", "2"], timeout=600)
    ckpt = _train(data, tmp_path / "train")
    config = json.loads((ckpt / "config.json").read_text())
    assert "observation.pointcloud" in config["input_features"]  # the policy consumes the cloud ...

    metrics = tmp_path / "episodes.jsonl"
    out, info, episodes = _eval(
        ckpt, ["--env.type=focal_metaworld", "--env.task=reach", "--env.episode_length=60"], tmp_path / "eval",
        metrics,
    )
    # ... and lerobot-eval delivered it (the policy raises on a missing required feature).
    overall = info["overall"]
    assert overall["n_episodes"] == 2 and 0.0 <= overall["pc_success"] <= 100.0
    assert len(episodes) == 2 and all(e["task"] == "reach-v3" for e in episodes)
    assert all(0 < e["length"] <= 60 and e["action_total_variation"] > 0 for e in episodes)
    assert len(re.findall(r"focal env episode: task=reach-v3 .* ATV=", out)) == 2
    atv = sum(e["action_total_variation"] for e in episodes) / len(episodes)
    print(f"\nfocal_metaworld reach: success {overall['pc_success']:.1f}% ATV {atv:.4f}")


@pytest.mark.slow
def test_minari_import_train_eval_adroit(tmp_path):
    pytest.importorskip("minari")
    pytest.importorskip("gymnasium_robotics")
    from tests.datasets.test_minari_import import DATASET_ID, _make_minari_dataset

    _make_minari_dataset(tmp_path / "minari")
    data = tmp_path / "data"
    _run([sys.executable, "-m", "lerobot_focal.datasets.making.minari_import", "--dataset_id", DATASET_ID, "--root",
          str(data), "--minari_root", str(tmp_path / "minari"), "--all_episodes"], timeout=600)
    ckpt = _train(data, tmp_path / "train", repo_id="local/focal_adroit")
    assert "observation.pointcloud" in json.loads((ckpt / "config.json").read_text())["input_features"]
    metrics = tmp_path / "episodes.jsonl"
    out, info, episodes = _eval(
        ckpt, ["--env.type=focal_adroit", "--env.task=door", "--env.episode_length=30"], tmp_path / "eval", metrics
    )
    assert info["overall"]["n_episodes"] == 2
    assert len(episodes) == 2 and all(e["task"] == "door" and e["length"] == 30 for e in episodes)
    assert all(e["action_total_variation"] > 0 for e in episodes)
    atv = sum(e["action_total_variation"] for e in episodes) / 2
    print(f"\nfocal_adroit door: success {info['overall']['pc_success']:.1f}% ATV {atv:.4f}")
