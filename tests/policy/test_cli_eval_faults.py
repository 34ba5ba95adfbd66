"""Faulty checkpoints through `lerobot-eval` on `focal_metaworld`, as a user meets them: each stops with a
message naming the problem and the fix instead of a bare library error or a silent 0 % with exit status 0.

The checkpoints are written with the plugin's own `save_pretrained` and processor factory (the same files
`lerobot-train` saves), then damaged the way a diverged run, a wrong environment or a broken copy damages them.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_focal.policy import FocalConfig, FocalPolicy, make_focal_pre_post_processors

pytestmark = pytest.mark.subprocess  # lerobot-eval on broken checkpoints

pytest.importorskip("metaworld")

BIN = Path(sys.executable).parent
ENV_ARGS = ["--env.type=focal_metaworld", "--env.task=reach", "--env.episode_length=16", "--env.render_videos=false"]


def _checkpoint(path: Path, *, cloud_channels: int) -> Path:
    """A small focal checkpoint for focal_metaworld reach (9-d state, 512-point cloud, 4-d action)."""
    inputs = {
        "observation.state": PolicyFeature(FeatureType.STATE, (9,)),
        "observation.pointcloud": PolicyFeature(FeatureType.STATE, (512, cloud_channels)),
    }
    cfg = FocalConfig(
        device="cpu", down_dims=(16, 32), use_pointcloud_color=cloud_channels == 6, input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, (4,))},
    )
    torch.manual_seed(0)
    policy = FocalPolicy(cfg)
    stats = {
        "observation.state": {"min": torch.full((9,), -1.0), "max": torch.full((9,), 1.0)},
        "observation.pointcloud": {
            "min": torch.full((cloud_channels,), -1.0), "max": torch.full((cloud_channels,), 1.0)
        },
        "action": {"min": torch.full((4,), -1.0), "max": torch.full((4,), 1.0)},
    }
    pre, post = make_focal_pre_post_processors(cfg, dataset_stats=stats)
    policy.save_pretrained(path)
    pre.save_pretrained(path)
    post.save_pretrained(path)
    return path


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return _checkpoint(tmp_path_factory.mktemp("ckpt") / "pretrained_model", cloud_channels=3)


def lerobot_eval(ckpt: Path, out: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    cmd = [
        str(BIN / "lerobot-eval"), f"--policy.path={ckpt}", *ENV_ARGS, "--eval.n_episodes=1", "--eval.batch_size=1",
        "--policy.device=cpu", f"--output_dir={out}",
    ]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)


def _copy(ckpt: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "pretrained_model"
    shutil.copytree(ckpt, dst)
    return dst


def test_nan_weights_stop_with_an_error_naming_the_checkpoint(checkpoint, tmp_path):
    """MuJoCo only warns about NaN controls: without the output check this evaluates to 0 % with exit 0."""
    ckpt = _copy(checkpoint, tmp_path)
    policy = FocalPolicy.from_pretrained(ckpt)
    with torch.no_grad():
        for module in (policy.model, policy.ema_model):
            next(module.velocity_net.parameters()).fill_(float("nan"))
    policy.save_pretrained(ckpt)

    proc = lerobot_eval(ckpt, tmp_path / "eval")
    assert proc.returncode != 0, proc.stdout[-2000:]
    assert "FocalPolicy produced" in proc.stderr and "NaN/inf action value(s)" in proc.stderr, proc.stderr[-3000:]
    assert f"Checkpoint: {ckpt / 'model.safetensors'}" in proc.stderr
    assert "weight tensor(s) of the EMA network are NaN/inf (velocity_net." in proc.stderr
    assert not (tmp_path / "eval" / "eval_info.json").exists()


def test_pointcloud_channel_mismatch_is_named_before_normalising(tmp_path):
    ckpt = _checkpoint(tmp_path / "pretrained_model", cloud_channels=6)
    proc = lerobot_eval(ckpt, tmp_path / "eval")
    assert proc.returncode != 0
    assert "'observation.pointcloud' has shape (1, 512, 3), but this policy was trained on (P, 6)" in proc.stderr, (
        proc.stderr[-3000:]
    )
    assert "xyz+rgb (P, 6) point clouds and was given xyz (P, 3)" in proc.stderr
    assert "must match the size of tensor" not in proc.stderr


@pytest.mark.parametrize("damage", ["truncated", pytest.param("empty", marks=pytest.mark.slow),  # ~15 s each
                                    pytest.param("garbled_header", marks=pytest.mark.slow)])
def test_corrupt_weights_file_is_named(damage, checkpoint, tmp_path):
    ckpt = _copy(checkpoint, tmp_path)
    weights = ckpt / "model.safetensors"
    data = weights.read_bytes()
    if damage == "truncated":
        weights.write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        weights.write_bytes(b"")
    else:
        weights.write_bytes(data[:8] + b"{garbled" + data[16:])

    proc = lerobot_eval(ckpt, tmp_path / "eval")
    assert proc.returncode != 0
    assert f"Checkpoint weights {weights} (" in proc.stderr, proc.stderr[-3000:]
    assert "are corrupt or incomplete" in proc.stderr and "download the checkpoint again" in proc.stderr
