"""The Hub path up to the network: `lerobot-train --policy.push_to_hub=true` and `lerobot-focal-collect
--push_to_hub` as real subprocesses. The one stub is the upload itself (tests/policy/hub_stub_site: the folder
that would be uploaded is copied to a local directory instead); what lands there must load back as a policy."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from lerobot_focal.datasets.making.synthetic import SyntheticSpec, write_synthetic_dataset

pytestmark = pytest.mark.subprocess  # lerobot-train and lerobot-focal-collect up to the (stubbed) upload

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
STUB_SITE = Path(__file__).resolve().parent / "hub_stub_site"


def _env(hub: Path) -> dict[str, str]:
    path = os.pathsep.join([str(STUB_SITE), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "PYTHONPATH": path,
            "FOCAL_HUB_STUB_DIR": str(hub)}


def test_train_pushes_a_folder_that_loads_back_with_a_focal_model_card(tmp_path):
    root = tmp_path / "dataset"
    write_synthetic_dataset(root, SyntheticSpec(num_episodes=2, episode_length=20, num_points=64))
    hub = tmp_path / "hub"
    cmd = [str(BIN / "lerobot-train"), f"--config_path={REPO / 'configs' / 'focal_cpu_state.json'}",
           "--dataset.repo_id=local/focal_synthetic", f"--dataset.root={root}", f"--output_dir={tmp_path / 'run'}",
           "--policy.push_to_hub=true", "--policy.repo_id=someone/focal_synthetic", "--policy.use_env_state=false",
           "--steps=3", "--save_freq=3", "--log_freq=1", "--batch_size=4"]
    proc = subprocess.run(cmd, cwd=tmp_path, env=_env(hub), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    assert "Model pushed to stub://someone/focal_synthetic" in proc.stdout + proc.stderr

    pushed = hub / "someone" / "focal_synthetic"
    for name in ("config.json", "model.safetensors", "train_config.json", "README.md", "policy_preprocessor.json",
                 "policy_postprocessor.json"):
        assert (pushed / name).is_file(), f"{name} not in the pushed folder: {sorted(os.listdir(pushed))}"
    weights = load_file(pushed / "model.safetensors")
    assert any(k.startswith("ema_model.") for k in weights) and "ema_step" in weights  # the EMA travels
    card = (pushed / "README.md").read_text()
    assert "license: apache-2.0" in card
    from lerobot.policies.pretrained import PreTrainedPolicy

    if hasattr(PreTrainedPolicy, "generate_model_card"):  # 0.6.1: the push asks the policy for its card
        assert "FocalPolicy" in card and "ICML 2026" in card and "Locally Anchored Sampling" in card
        tags = ("focal", "focalpolicy", "flow-matching", "lerobot", "robotics")
    else:  # LeRobot main renders its own card from the config alone (docs/compatibility.md)
        assert "This is a **focal** policy trained with" in card
        tags = ("focal", "lerobot", "robotics")
    for tag in tags:
        assert f"- {tag}\n" in card, f"tag {tag} missing"

    # What a user of --policy.path gets: LeRobot's own loaders on the pushed folder, then one action.
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    cfg = PreTrainedConfig.from_pretrained(pushed)
    policy = get_policy_class(cfg.type).from_pretrained(pushed, config=cfg).eval()
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(pushed))
    obs = {k: torch.zeros(1, *cfg.input_features[k].shape) for k in ("observation.state", "observation.pointcloud")}
    action = post(policy.select_action(pre(obs)))
    assert action.shape == (1, cfg.output_features["action"].shape[0]) and torch.isfinite(action).all()


@pytest.mark.slow  # ~15 s; the push itself is the training test's above
def test_collect_push_to_hub_uploads_the_finished_dataset(tmp_path):
    pytest.importorskip("metaworld")
    hub = tmp_path / "hub"
    cmd = [sys.executable, "-m", "lerobot_focal.datasets.making.collect", "--root", str(tmp_path / "mw"),
           "--repo_id", "someone/mw_reach", "--tasks", "reach", "--episodes", "1", "--obs_types", "state",
           "--push_to_hub"]
    proc = subprocess.run(cmd, cwd=tmp_path, env=_env(hub), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    pushed = hub / "someone" / "mw_reach"
    info = json.loads((pushed / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 1 and "observation.state" in info["features"]
    assert list(pushed.glob("data/**/*.parquet")) and (pushed / "README.md").is_file()
    # Collection bookkeeping (seed state, the per-episode commit record) stays local.
    assert not (pushed / ".focal_commit").exists() and not (pushed / "focal_collect_state.json").exists()
