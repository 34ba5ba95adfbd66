"""`lerobot-train --policy.type=focal` as a user runs it: a real subprocess, no plugin-discovery flags.

The dataset has every observation kind the policy reads (state, point cloud, one camera). The run starts from
the repository's CPU preset (`--config_path=configs/focal_cpu.json`), saves, is resumed from its checkpoint,
and the checkpoint then loads with LeRobot's own `make_policy` / `from_pretrained` and saved processors.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_policy, make_pre_post_processors

from lerobot_focal.datasets.making.synthetic import SyntheticSpec, write_synthetic_dataset
from lerobot_focal.policy import FocalPolicy

pytestmark = pytest.mark.subprocess  # real lerobot-train runs

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def _train(*args: str, cwd: Path, **extra_env: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", **extra_env}
    proc = subprocess.run([str(BIN / "lerobot-train"), *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)
    if proc.returncode != 0:
        raise AssertionError(f"lerobot-train failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return proc


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli")
    root = tmp / "dataset"
    spec = SyntheticSpec(num_episodes=3, episode_length=20, num_points=64, with_image=True, image_size=32)
    write_synthetic_dataset(root, spec)
    out = tmp / "run"
    first = _train(
        f"--config_path={REPO / 'configs' / 'focal_cpu.json'}",
        "--dataset.repo_id=local/focal_synthetic",
        f"--dataset.root={root}",
        f"--output_dir={out}",
        "--policy.down_dims=[32,64,128]",
        "--policy.spatial_softmax_num_keypoints=8",
        "--steps=4",
        "--save_freq=2",
        "--log_freq=1",
        "--batch_size=4",
        cwd=tmp,
        # The first run uses the plugin's opt-in fast reader, the resumed one LeRobot's stock reader.
        LEROBOT_FOCAL_FAST_READER="1",
    )
    return tmp, root, out, first


def test_train_saves_checkpoints_with_processors(trained_run):
    _, _, out, first = trained_run
    log = first.stdout + first.stderr
    assert "focal" in log
    # LEROBOT_FOCAL_FAST_READER=1 reached lerobot-train via the plugin; on a LeRobot whose reader differs from the
    # verified one (e.g. its main branch, docs/compatibility.md) it says so and training reads the stock way.
    from lerobot_focal.datasets.fast_loading.fast_reader import compatible

    assert ("columns cached in memory" if compatible()[0] else "fast reader NOT installed") in log
    for step in ("000002", "000004"):
        model_dir = out / "checkpoints" / step / "pretrained_model"
        for name in ("config.json", "model.safetensors", "train_config.json"):
            assert (model_dir / name).is_file(), f"missing {model_dir / name}"
        assert list(model_dir.glob("policy_preprocessor*.json")) and list(model_dir.glob("policy_postprocessor*.json"))
    cfg = json.loads((out / "checkpoints" / "last" / "pretrained_model" / "config.json").read_text())
    assert cfg["type"] == "focal" and cfg["down_dims"] == [32, 64, 128]
    # All three observation kinds made it into the policy's features.
    assert {"observation.state", "observation.pointcloud", "observation.images.front"} <= set(cfg["input_features"])
    # The policy's optimizer preset (fused AdamW) is named in the checkpoint, so --resume rebuilds it.
    train_cfg = json.loads((out / "checkpoints" / "last" / "pretrained_model" / "train_config.json").read_text())
    assert train_cfg["optimizer"]["type"] == "focal_adamw" and train_cfg["optimizer"]["lr"] == cfg["optimizer_lr"]


def test_resume_continues_from_the_saved_step(trained_run):
    tmp, _, out, _ = trained_run
    train_cfg = out / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    resumed = _train(f"--config_path={train_cfg}", "--resume=true", "--steps=6", cwd=tmp, LEROBOT_FOCAL_FAST_READER="0")
    assert "columns cached in memory" not in resumed.stdout + resumed.stderr
    assert (out / "checkpoints" / "000006" / "pretrained_model" / "model.safetensors").is_file()
    state = json.loads((out / "checkpoints" / "last" / "training_state" / "training_step.json").read_text())
    assert state["step"] == 6
    # The EMA step counter is part of the weights: a resumed run continues it instead of restarting at 0.
    policy = FocalPolicy.from_pretrained(out / "checkpoints" / "last" / "pretrained_model")
    assert int(policy.ema_step.item()) == 6


def test_checkpoint_loads_with_make_policy_and_processors(trained_run):
    _, root, out, _ = trained_run
    model_dir = out / "checkpoints" / "last" / "pretrained_model"
    ds = LeRobotDataset("local/focal_synthetic", root=root)

    cfg = PreTrainedConfig.from_pretrained(model_dir)
    cfg.pretrained_path = model_dir
    via_factory = make_policy(cfg, ds_meta=ds.meta)
    via_base = FocalPolicy.from_pretrained(model_dir)  # PreTrainedPolicy.from_pretrained, as lerobot-eval calls it
    assert isinstance(via_factory, FocalPolicy)
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(model_dir))

    frame = ds[5]
    obs = {k: v[None] for k, v in frame.items() if k.startswith("observation.")}
    outputs = []
    for policy in (via_factory, via_base):
        policy.eval()
        policy.reset()
        torch.manual_seed(0)
        with torch.no_grad():
            outputs.append(post(policy.select_action(pre(dict(obs)))))
    assert outputs[0].shape == (1, 3)
    assert torch.isfinite(outputs[0]).all()
    torch.testing.assert_close(outputs[0], outputs[1])
