"""The policy on both LeRobot APIs it meets (docs/compatibility.md): 0.6.1 (this venv in CI) and LeRobot's main
branch (``scripts/test_lerobot_main.sh <lerobot tree>`` runs this file in a venv with it). Each test checks what
the installed LeRobot has; the ``--ema.enable`` ones only run where that option exists."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from lerobot.configs import train as lerobot_train_config
from lerobot.policies.pretrained import PreTrainedPolicy

from lerobot_focal.datasets.making.synthetic import SyntheticSpec, write_synthetic_dataset
from lerobot_focal.policy.lerobot_compat import refuse_stacked_ema, running_train_config
from tests.policy.helpers import small_policy

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
HAS_GLOBAL_EMA = "ema" in lerobot_train_config.TrainPipelineConfig.__dataclass_fields__
needs_global_ema = pytest.mark.skipif(not HAS_GLOBAL_EMA, reason="this LeRobot has no --ema.enable (0.6.1)")


def test_model_card_is_focals_on_either_card_api(monkeypatch):
    from huggingface_hub import RepoCard

    monkeypatch.setattr(RepoCard, "validate", lambda self, repo_type=None: None)  # the Hub's YAML check is online
    policy = small_policy()
    card = policy.generate_model_card("someone/data", "focal", None, ["mine"])
    text = str(card)
    assert "FocalPolicy" in text and "Locally Anchored Sampling" in text
    assert "This is a **focal** policy trained with" in text  # LeRobot's own card follows focal's intro
    assert card.data.license == "apache-2.0" and card.data.datasets == "someone/data"
    assert {"mine", "focal", "focalpolicy", "flow-matching", "lerobot", "robotics"} <= set(card.data.tags)
    # On LeRobot main the card comes from the free function, which reads license and tags from a config: the
    # policy's own config is left untouched.
    assert policy.config.tags is None and policy.config.license is None
    if not hasattr(PreTrainedPolicy, "generate_model_card"):
        from lerobot.common.train_utils import generate_model_card  # the API the method fell back on

        assert callable(generate_model_card)


class TrainPipelineConfig:
    """A stand-in with what the frame lookup recognises: LeRobot's class name, ``policy`` and ``ema.enable``."""

    def __init__(self, policy, ema_enable: bool):
        self.policy, self.ema = policy, SimpleNamespace(enable=ema_enable)


def _build_inside_train(policy_config, ema_enable: bool):
    cfg = TrainPipelineConfig(policy_config, ema_enable)  # noqa: F841 - found by running_train_config
    refuse_stacked_ema(policy_config)
    return running_train_config(policy_config)


def test_two_emas_are_refused_and_one_is_fine():
    policy_config = small_policy().config
    refusal = r"--ema.enable=true.*--policy.use_ema=false --policy.consistency_target=online"
    with pytest.raises(ValueError, match=refusal):
        _build_inside_train(policy_config, ema_enable=True)
    assert _build_inside_train(policy_config, ema_enable=False).policy is policy_config
    online = small_policy(use_ema=False, consistency_target="online").config
    assert _build_inside_train(online, ema_enable=True).policy is online  # LeRobot's EMA alone
    refuse_stacked_ema(policy_config)  # outside lerobot-train (eval, rollout, scripts): nothing to check
    other = small_policy().config
    cfg = TrainPipelineConfig(other, ema_enable=True)  # noqa: F841 - another policy's run is not this one's
    assert running_train_config(policy_config) is None


def test_diffusion_ema_refuses_the_second_ema_too():
    from lerobot_focal.policy.diffusion_ema import DiffusionEmaConfig

    with pytest.raises(ValueError, match=r"beside diffusion_ema's own EMA.*alone with --policy.use_ema=false\."):
        _build_inside_train(DiffusionEmaConfig(), ema_enable=True)
    plain = DiffusionEmaConfig(use_ema=False, use_ema_for_inference=False)
    assert _build_inside_train(plain, ema_enable=True).policy is plain


def _train(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    root = tmp_path / "dataset"
    if not root.exists():
        write_synthetic_dataset(root, SyntheticSpec(num_episodes=2, episode_length=20, num_points=64))
    cmd = [str(BIN / "lerobot-train"), f"--config_path={REPO / 'configs' / 'focal_cpu_state.json'}",
           "--dataset.repo_id=local/focal_synthetic", f"--dataset.root={root}", "--policy.use_env_state=false",
           "--policy.push_to_hub=false", "--steps=3", "--save_freq=3", "--log_freq=1", "--batch_size=4", *args]
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    return subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)


@needs_global_ema
def test_lerobot_train_refuses_ema_enable_beside_focals_ema(tmp_path):
    proc = _train(tmp_path, f"--output_dir={tmp_path / 'run'}", "--ema.enable=true")
    assert proc.returncode != 0
    log = proc.stdout + proc.stderr
    assert "--ema.enable=true adds LeRobot's EMA" in log and "--policy.use_ema=false" in log
    assert "Start offline training" not in log and not (tmp_path / "run" / "checkpoints").exists()


@needs_global_ema
def test_lerobot_train_with_lerobots_ema_alone_saves_and_loads_its_shadow(tmp_path):
    out = tmp_path / "run"
    proc = _train(tmp_path, f"--output_dir={out}", "--ema.enable=true", "--policy.use_ema=false",
                  "--policy.consistency_target=online")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    shadow = out / "checkpoints" / "last" / "pretrained_model_ema"
    assert (shadow / "model.safetensors").is_file(), sorted(p.name for p in shadow.parent.iterdir())
    from safetensors.torch import load_file

    live = load_file(shadow.parent / "pretrained_model" / "model.safetensors")
    ema = load_file(shadow / "model.safetensors")
    assert live.keys() == ema.keys() and any(not torch.equal(live[k], ema[k]) for k in live)  # a shadow, not a copy

    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    cfg = PreTrainedConfig.from_pretrained(shadow)
    policy = get_policy_class(cfg.type).from_pretrained(shadow, config=cfg).eval()
    assert policy.ema_model is None
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(shadow))
    obs = {k: torch.zeros(1, *cfg.input_features[k].shape) for k in cfg.input_features}
    action = post(policy.select_action(pre(obs)))
    assert action.shape == (1, cfg.output_features["action"].shape[0]) and torch.isfinite(action).all()
