"""``diffusion_ema``: LeRobot's diffusion policy with an EMA copy on DP3's schedule, acting with the EMA weights.

Real policies, real LeRobot code, no mocks:
  * training is LeRobot's ``DiffusionPolicy`` loss bit for bit (same weights, same seed), and the optimizer sees
    only the online network;
  * ``update()`` moves the EMA copy by DP3's decay (the formula written out here);
  * inference samples with the EMA network (and with the online one when told so);
  * ``lerobot-train --policy.type=diffusion_ema`` runs as a subprocess on a tiny on-disk dataset; its checkpoint
    holds EMA weights that differ from the online ones, the EMA step count equals the training steps, and it
    reloads through ``make_policy`` / ``from_pretrained`` with the EMA weights intact and acts.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.diffusion import DiffusionConfig, DiffusionPolicy
from lerobot.policies.factory import get_policy_class, make_pre_post_processors
from safetensors.torch import load_file

from lerobot_focal.config_errors import ConfigError
from lerobot_focal.policy.diffusion_ema import DiffusionEmaConfig, DiffusionEmaPolicy
from tests.policy.test_diffusion_fco import (
    ACT,
    HORIZON,
    N_ACT,
    _batch,
    _config as _fco_config,
    _write_dataset,
    reload_and_act,
)

BIN = Path(sys.executable).parent


def _config(**overrides) -> DiffusionEmaConfig:
    """The small diffusion config of the diffusion_fco tests (same features, horizon, U-Net), as diffusion_ema."""
    base = _fco_config()
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(DiffusionConfig) if f.init}
    return DiffusionEmaConfig(**{**fields, "num_inference_steps": 3, "noise_scheduler_type": "DDIM", **overrides})


def test_training_is_lerobot_diffusion_and_the_optimizer_sees_only_the_online_network():
    torch.manual_seed(0)
    policy = DiffusionEmaPolicy(_config())
    fields = {f.name: getattr(policy.config, f.name) for f in dataclasses.fields(DiffusionConfig) if f.init}
    twin = DiffusionPolicy(DiffusionConfig(**fields))
    twin.load_state_dict({k: v for k, v in policy.state_dict().items()
                          if not k.startswith("ema_diffusion.") and k != "ema_step"})
    batch = _batch()
    torch.manual_seed(5)
    ours, _ = policy.forward(dict(batch))
    torch.manual_seed(5)
    ref, _ = twin.forward(dict(batch))
    assert torch.equal(ours, ref)
    optimised = {id(p) for p in policy.get_optim_params()}
    assert optimised == {id(p) for p in policy.diffusion.parameters()}
    assert not any(p.requires_grad for p in policy.ema_diffusion.parameters())
    assert policy.config.noise_scheduler_type == "DDIM" and policy.config.num_inference_steps == 3
    assert DiffusionEmaConfig().num_inference_steps == 10  # DP3's inference by default


def test_update_follows_dp3_schedule():
    policy = DiffusionEmaPolicy(_config())
    online = next(policy.diffusion.parameters())
    ema = next(policy.ema_diffusion.parameters())
    for step in range(6):
        with torch.no_grad():
            online.add_(0.25)
        before = ema.detach().clone()
        policy.update()
        s = step - 1  # DP3's EMAModel: optimization step − update_after_step − 1
        decay = 0.0 if s <= 0 else min(1 - (1 + s) ** -0.75, 0.9999)
        torch.testing.assert_close(ema, decay * before + (1 - decay) * online.detach())
    assert int(policy.ema_step) == 6
    assert not torch.equal(ema, online)
    policy.train()
    assert policy.training and not policy.ema_diffusion.training


def parted_and_counted(policy: DiffusionEmaPolicy) -> dict[str, int]:
    """`policy` in eval mode with EMA weights that differ from the online ones (so the two networks give different
    chunks), and the U-Net calls of each network, counted from now on."""
    with torch.no_grad():
        for p in policy.ema_diffusion.parameters():
            p.add_(0.1)
    calls = {"online": 0, "ema": 0}
    policy.diffusion.unet.register_forward_hook(lambda *_: calls.__setitem__("online", calls["online"] + 1))
    policy.ema_diffusion.unet.register_forward_hook(lambda *_: calls.__setitem__("ema", calls["ema"] + 1))
    policy.eval()
    return calls


@pytest.mark.parametrize("use_ema_for_inference", [True, False])
def test_inference_uses_the_ema_network(use_ema_for_inference):
    policy = DiffusionEmaPolicy(_config(use_ema_for_inference=use_ema_for_inference))
    calls = parted_and_counted(policy)
    obs = {k: v[:1, -1] for k, v in _batch().items() if k.startswith("observation.")}
    with torch.no_grad():
        action = policy.select_action(dict(obs))
    assert action.shape == (1, ACT)
    used, unused = ("ema", "online") if use_ema_for_inference else ("online", "ema")
    assert calls[used] == 3 and calls[unused] == 0  # num_inference_steps U-Net calls, all on one network
    assert policy._modules["diffusion"] is not policy.ema_diffusion  # the online network is back in place


def test_config_validation_and_factory_resolution():
    for bad in (dict(ema_max_decay=1.0), dict(ema_min_decay=0.5, ema_max_decay=0.4), dict(ema_power=0.0),
                dict(use_ema=False)):
        with pytest.raises(ConfigError, match="--policy.type=diffusion_ema"):
            _config(**bad)
    plain = DiffusionEmaPolicy(_config(use_ema=False, use_ema_for_inference=False))
    assert plain.ema_diffusion is None
    plain.update()  # nothing to update
    assert "diffusion_ema" in PreTrainedConfig.get_known_choices()
    assert get_policy_class("diffusion_ema") is DiffusionEmaPolicy
    cfg = _config()
    stats = {k: {"min": torch.full(f.shape, -1.0), "max": torch.full(f.shape, 1.0)}
             for k, f in {**cfg.input_features, **cfg.output_features}.items()}
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)  # resolved by naming convention
    assert pre is not None and post is not None


# ----------------------------------------------------------------------------------------------- lerobot-train

STEPS = 4


#: A tiny U-Net of LeRobot's diffusion on the CPU, not pushed anywhere.
TINY_DIFFUSION_ARGS = (
    "--policy.device=cpu",
    "--policy.push_to_hub=false",
    "--policy.down_dims=[16,32]",
    "--policy.kernel_size=3",
    "--policy.n_groups=4",
    "--policy.diffusion_step_embed_dim=16",
)


def tiny_train_run(policy_args: list[str], root: Path, repo_id: str, out: Path, steps: int) -> None:
    """`lerobot-train` with `policy_args` on the dataset at `root`: `steps` steps of batch 4 on one CPU thread,
    offline, saving at the last; an AssertionError with the output's tail if it fails."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    args = [
        str(BIN / "lerobot-train"),
        *policy_args,
        f"--dataset.repo_id={repo_id}",
        f"--dataset.root={root}",
        f"--output_dir={out}",
        f"--steps={steps}",
        f"--save_freq={steps}",
        "--log_freq=1",
        "--batch_size=4",
        "--num_workers=0",
        "--wandb.enable=false",
    ]
    proc = subprocess.run(args, cwd=out.parent, env=env, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise AssertionError(f"lerobot-train failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")


def last_checkpoint(out: Path, steps: int) -> tuple[Path, dict, dict[str, torch.Tensor]]:
    """The folder, config.json and weights of a run's last checkpoint, whose EMA has had one update per step."""
    model_dir = out / "checkpoints" / "last" / "pretrained_model"
    weights = load_file(str(model_dir / "model.safetensors"))
    assert int(weights["ema_step"]) == steps  # update() ran after every optimizer step
    return model_dir, json.loads((model_dir / "config.json").read_text()), weights


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dp_ema")
    root, out = tmp / "dataset", tmp / "run"
    _write_dataset(root)
    policy_args = [
        "--policy.type=diffusion_ema",
        *TINY_DIFFUSION_ARGS,
        f"--policy.horizon={HORIZON}",
        f"--policy.n_action_steps={N_ACT}",
        "--policy.num_inference_steps=4",
        "--policy.optimizer_lr=1e-2",  # large steps, so that online and EMA weights part visibly in 4 steps
    ]
    tiny_train_run(policy_args, root, "local/dp_fco_tiny", out, STEPS)
    return root, out


@pytest.mark.subprocess
def test_lerobot_train_diffusion_ema_checkpoint_holds_the_ema_and_reloads(trained):
    root, out = trained
    model_dir, saved, weights = last_checkpoint(out, STEPS)
    assert saved["type"] == "diffusion_ema" and saved["use_ema"] is True and saved["num_inference_steps"] == 4
    online = {k.removeprefix("diffusion."): v for k, v in weights.items() if k.startswith("diffusion.")}
    ema = {k.removeprefix("ema_diffusion."): v for k, v in weights.items() if k.startswith("ema_diffusion.")}
    assert online.keys() == ema.keys() and online
    differing = [k for k in online if online[k].is_floating_point() and not torch.equal(online[k], ema[k])]
    assert len(differing) > len(online) // 2, "EMA weights should differ from the online ones after training"

    for policy in reload_and_act(model_dir, root, "local/dp_fco_tiny", DiffusionEmaPolicy):
        assert int(policy.ema_step) == STEPS
        for k, v in policy.ema_diffusion.state_dict().items():
            torch.testing.assert_close(v, ema[k])
