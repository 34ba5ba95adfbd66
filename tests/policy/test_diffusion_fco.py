"""``diffusion_fco`` ("DP w. FCO", paper Table 2): LeRobot's diffusion policy plus FCO on the x̂0 estimate.

Real policies, real LeRobot code, no mocks:
  * FCO off → the loss is LeRobot's ``DiffusionPolicy`` loss bit for bit (same weights, same seed);
  * FCO on → the extra term equals FCO recomputed here from scratch (noise/timestep draws, ᾱ_t from the
    scheduler's betas, x̂0 by hand, min-SNR-γ weights, scipy's orthonormal DCT) for ε- and sample-prediction;
  * gradients of the FCO term reach the network;
  * ``lerobot-train --policy.type=diffusion_fco`` runs as a subprocess on a tiny on-disk dataset and its
    checkpoint reloads through ``make_policy`` / ``from_pretrained`` / saved processors and acts.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.fft
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.diffusion import DiffusionConfig, DiffusionPolicy
from lerobot.policies.factory import get_policy_class, make_policy, make_pre_post_processors

from lerobot_focal.config_errors import ConfigError
from lerobot_focal.policy.diffusion_fco import DiffusionFcoConfig, DiffusionFcoPolicy

BIN = Path(sys.executable).parent
STATE, ENV, ACT = 4, 6, 2
B, HORIZON, N_OBS, N_ACT = 6, 16, 2, 8


def _config(**overrides) -> DiffusionFcoConfig:
    kwargs = dict(
        device="cpu",
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (STATE,)),
            "observation.environment_state": PolicyFeature(FeatureType.ENV, (ENV,)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (ACT,))},
        horizon=HORIZON,
        n_obs_steps=N_OBS,
        n_action_steps=N_ACT,
        down_dims=(16, 32),
        kernel_size=3,
        n_groups=4,
        diffusion_step_embed_dim=16,
    )
    kwargs.update(overrides)
    return DiffusionFcoConfig(**kwargs)


def _batch(seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    t = torch.linspace(0, 1, HORIZON)
    # Smooth, normalised-range action trajectories (as min-max normalised actions are).
    phase = torch.rand(B, 1, ACT, generator=g) * 6.28
    actions = 0.8 * torch.sin(3.0 * t[None, :, None] + phase)
    pad = torch.zeros(B, HORIZON, dtype=torch.bool)
    pad[0, -3:] = True
    return {
        "observation.state": torch.rand(B, N_OBS, STATE, generator=g) * 2 - 1,
        "observation.environment_state": torch.rand(B, N_OBS, ENV, generator=g) * 2 - 1,
        "action": actions,
        "action_is_pad": pad,
    }


def _loss(policy, batch, seed: int = 123):
    torch.manual_seed(seed)
    return policy.forward(dict(batch))


def _lerobot_twin(policy: DiffusionFcoPolicy) -> DiffusionPolicy:
    """LeRobot's own DiffusionPolicy with the same DiffusionConfig fields and the same weights."""
    cfg = policy.config
    fields = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(DiffusionConfig) if f.init}
    twin = DiffusionPolicy(DiffusionConfig(**fields))
    twin.load_state_dict(policy.state_dict())
    return twin


@pytest.mark.parametrize("mask_padding", [False, True])
def test_fco_off_is_lerobot_diffusion_loss(mask_padding):
    torch.manual_seed(0)
    policy = DiffusionFcoPolicy(_config(use_fco=False, do_mask_loss_for_padding=mask_padding))
    twin = _lerobot_twin(policy)
    batch = _batch()
    ours, out = _loss(policy, batch)
    ref, _ = _loss(twin, batch)
    assert out is None
    assert torch.equal(ours, ref), (ours, ref)
    # With FCO on, the diffusion part is still exactly that loss (same noise, timesteps, network call).
    policy.config.use_fco = True
    on, logs = _loss(policy, batch)
    assert logs["loss_diffusion"] == pytest.approx(ref.item(), rel=1e-6)
    assert not torch.isclose(on, ref)


def _expected_fco(policy: DiffusionFcoPolicy, batch, seed: int = 123) -> tuple[float, float]:
    """L_time and L_freq recomputed from scratch: the draws of LeRobot's compute_loss, then x̂0 and DCT by hand."""
    cfg = policy.config
    x0 = batch["action"]
    torch.manual_seed(seed)
    eps = torch.randn(x0.shape)
    t = torch.randint(0, cfg.num_train_timesteps, (x0.shape[0],)).long()
    alpha_bar = torch.cumprod(1.0 - policy.diffusion.noise_scheduler.betas.double(), 0)[t].view(-1, 1, 1)
    noisy = (alpha_bar.sqrt() * x0.double() + (1 - alpha_bar).sqrt() * eps.double()).float()
    cond = torch.cat([batch["observation.state"], batch["observation.environment_state"]], -1).flatten(1)
    with torch.no_grad():
        out = policy.diffusion.unet(noisy, t, global_cond=cond).double()
    if cfg.prediction_type == "epsilon":
        x0_hat = (noisy.double() - (1 - alpha_bar).sqrt() * out) / alpha_bar.sqrt()
    else:
        x0_hat = out
    x0_hat = x0_hat.clamp(-cfg.clip_sample_range, cfg.clip_sample_range).numpy()
    err = x0_hat - x0.double().numpy()
    # Min-SNR-γ weights (ε-prediction): min(ᾱ/(1−ᾱ), γ) per sample; sample prediction is unweighted.
    snr = (alpha_bar / (1 - alpha_bar)).flatten().numpy()
    weighted = cfg.prediction_type == "epsilon" and cfg.fco_weighting == "min_snr"
    w = np.minimum(snr, cfg.fco_min_snr_gamma) if weighted else np.ones_like(snr)
    s = N_OBS - 1
    l_time = float((w * (err[:, s : s + N_ACT] ** 2).mean(axis=(1, 2))).mean())
    coeffs = scipy.fft.dct(err, type=2, norm="ortho", axis=1)  # orthonormal DCT-II over the whole horizon
    l_freq = float((w * (coeffs**2).sum(axis=(1, 2))).mean())
    assert l_freq == pytest.approx(float((w * (err**2).sum(axis=(1, 2))).mean()), rel=1e-9)  # Parseval
    return l_time, l_freq


@pytest.mark.parametrize(
    ("prediction_type", "weighting"), [("epsilon", "min_snr"), ("epsilon", "none"), ("sample", "min_snr")]
)
def test_fco_term_is_fco_on_x0_estimate(prediction_type, weighting):
    torch.manual_seed(1)
    lam = 1e-2  # larger than the paper's 1e-4 so that the frequency term is well above float noise
    policy = DiffusionFcoPolicy(_config(prediction_type=prediction_type, fco_lambda=lam, fco_weighting=weighting))
    batch = _batch(seed=2)
    on, logs = _loss(policy, batch)
    policy.config.use_fco = False
    off, _ = _loss(policy, batch)
    l_time, l_freq = _expected_fco(policy, batch)
    assert l_time > 0 and l_freq > 0
    assert logs["loss_time"] == pytest.approx(l_time, rel=1e-4)
    assert logs["loss_freq"] == pytest.approx(l_freq, rel=1e-4)
    assert (on - off).item() == pytest.approx(l_time + lam * l_freq, rel=1e-4)
    assert logs["loss_fco"] == pytest.approx(l_time + lam * l_freq, rel=1e-4)

    # FCO alone (the paper's literal DP3 variant with sample prediction) is exactly that extra term.
    policy.config.use_fco, policy.config.fco_keep_diffusion_loss = True, False
    alone, _ = _loss(policy, batch)
    assert alone.item() == pytest.approx(l_time + lam * l_freq, rel=1e-4)


def test_min_snr_weighting_keeps_fco_within_the_epsilon_loss_scale():
    """Unweighted, FCO's gradient on ε̂ is the ε-loss's times 1/SNR_t (millions at the noisiest step); with
    min(SNR_t, γ) its per-element weight in ε units is min(1, γ/SNR_t) ≤ 1 at every step of the schedule."""
    policy = DiffusionFcoPolicy(_config())
    t = torch.arange(policy.config.num_train_timesteps)
    alpha_bar = policy.diffusion.noise_scheduler.alphas_cumprod.float()
    snr = alpha_bar / (1 - alpha_bar)
    w = policy.fco_sample_weights(t)
    assert w is not None and torch.allclose(w, snr.clamp(max=5.0))
    assert (w / snr).max() <= 1.0 + 1e-6  # x̂0 weight → ε weight: divide by SNR
    assert (1 / snr).max() > 1e6  # what the weighting prevents: the unweighted x̂0 loss's worst ε weight
    policy.config.fco_weighting = "none"
    assert policy.fco_sample_weights(t) is None
    policy.config.fco_weighting, policy.config.prediction_type = "min_snr", "sample"
    assert policy.fco_sample_weights(t) is None


def test_gradient_of_fco_reaches_the_network():
    torch.manual_seed(2)
    policy = DiffusionFcoPolicy(_config(fco_keep_diffusion_loss=False, fco_lambda=1e-4))
    loss, _ = _loss(policy, _batch(seed=3))
    assert loss.requires_grad and torch.isfinite(loss)
    loss.backward()
    grads = {n: p.grad for n, p in policy.named_parameters()}
    assert all(g is None or torch.isfinite(g).all() for g in grads.values())
    # Through the U-Net's output layer and through the observation conditioning (FiLM encoder).
    final = [n for n in grads if n.startswith("diffusion.unet.final_conv") and n.endswith("weight")]
    film = [n for n in grads if "cond_encoder" in n and n.endswith("weight")]
    assert final and film
    assert all(grads[n] is not None and grads[n].abs().sum() > 0 for n in final + film)


def test_config_validation_and_factory_resolution():
    with pytest.raises(ConfigError, match="fco_time_window"):
        _config(fco_time_window="proximal")
    with pytest.raises(ConfigError, match="executed window"):
        _config(n_action_steps=16)
    with pytest.raises(ConfigError, match="fco_weighting"):
        _config(fco_weighting="snr")
    for gamma in (0.0, float("nan")):
        with pytest.raises(ConfigError, match="fco_min_snr_gamma"):
            _config(fco_min_snr_gamma=gamma)
    assert "diffusion_fco" in PreTrainedConfig.get_known_choices()
    assert get_policy_class("diffusion_fco") is DiffusionFcoPolicy
    cfg = _config()
    assert cfg.type == "diffusion_fco"
    assert cfg.fco_window("executed") == slice(1, 9) and cfg.fco_window("horizon") == slice(0, 16)
    stats = {k: {"min": torch.full(f.shape, -1.0), "max": torch.full(f.shape, 1.0)}
             for k, f in {**cfg.input_features, **cfg.output_features}.items()}
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)  # resolved by naming convention
    assert pre is not None and post is not None


# ----------------------------------------------------------------------------------------------- lerobot-train


def _write_dataset(root: Path) -> None:
    feats = {
        "observation.state": {"dtype": "float32", "shape": (STATE,), "names": None},
        "observation.environment_state": {"dtype": "float32", "shape": (ENV,), "names": None},
        "action": {"dtype": "float32", "shape": (ACT,), "names": ["x", "y"]},
    }
    ds = LeRobotDataset.create(repo_id="local/dp_fco_tiny", fps=10, features=feats, root=root, use_videos=False)
    rng = np.random.default_rng(0)
    for _ in range(2):
        length = 30
        s = np.linspace(0, 1, length + 1, dtype=np.float32)[:, None]
        goal = rng.uniform(-1, 1, (1, ACT)).astype(np.float32)
        pos = goal * s
        for i in range(length):
            ds.add_frame(
                {
                    "observation.state": np.concatenate([pos[i], goal[0]]).astype(np.float32),
                    "observation.environment_state":
                        np.concatenate([goal[0], pos[i], goal[0] - pos[i]]).astype(np.float32),
                    "action": pos[i + 1],
                    "task": "reach",
                }
            )
        ds.save_episode()
    ds.finalize()


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dp_fco")
    root, out = tmp / "dataset", tmp / "run"
    _write_dataset(root)
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1",
           "LEROBOT_FOCAL_FAST_READER": "1"}
    args = [
        str(BIN / "lerobot-train"),
        "--policy.type=diffusion_fco",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        f"--policy.horizon={HORIZON}",
        f"--policy.n_action_steps={N_ACT}",
        "--policy.down_dims=[16,32]",
        "--policy.kernel_size=3",
        "--policy.n_groups=4",
        "--policy.diffusion_step_embed_dim=16",
        "--policy.noise_scheduler_type=DDIM",
        "--policy.num_inference_steps=4",
        "--dataset.repo_id=local/dp_fco_tiny",
        f"--dataset.root={root}",
        f"--output_dir={out}",
        "--steps=3",
        "--save_freq=3",
        "--log_freq=1",
        "--batch_size=4",
        "--num_workers=0",
        "--wandb.enable=false",
    ]
    proc = subprocess.run(args, cwd=tmp, env=env, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise AssertionError(f"lerobot-train failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return root, out, proc.stdout + proc.stderr


@pytest.mark.subprocess
def test_lerobot_train_diffusion_fco_checkpoint_reloads_and_acts(trained):
    root, out, log = trained
    assert "columns cached in memory" in log  # the plugin (and its fast reader) was loaded by lerobot-train
    model_dir = out / "checkpoints" / "last" / "pretrained_model"
    saved = json.loads((model_dir / "config.json").read_text())
    assert saved["type"] == "diffusion_fco" and saved["use_fco"] is True and saved["fco_lambda"] == 1e-4
    assert {"observation.state", "observation.environment_state"} <= set(saved["input_features"])
    state = json.loads((out / "checkpoints" / "last" / "training_state" / "training_step.json").read_text())
    assert state["step"] == 3

    via_factory, _ = reload_and_act(model_dir, root, "local/dp_fco_tiny", DiffusionFcoPolicy)
    assert via_factory.diffusion.num_inference_steps == 4


def reload_and_act(model_dir: Path, root: Path, repo_id: str, policy_cls: type) -> tuple:
    """A `lerobot-train` checkpoint reloaded as `--resume` and fine-tuning do (`make_policy` with the dataset) and
    as `lerobot-eval` does (`from_pretrained`): two `policy_cls` that act alike on a frame of the dataset."""
    ds = LeRobotDataset(repo_id, root=root)
    cfg = PreTrainedConfig.from_pretrained(model_dir)
    assert isinstance(cfg, policy_cls.config_class)
    cfg.pretrained_path = model_dir
    policies = (make_policy(cfg, ds_meta=ds.meta), policy_cls.from_pretrained(model_dir))
    assert all(isinstance(policy, policy_cls) for policy in policies)
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(model_dir))
    assert_same_first_action(policies, pre, post, ds[10])
    return policies


def assert_same_first_action(policies, pre, post, frame: dict) -> None:
    """Each policy's first action on `frame`'s observation, same noise seed: finite, (1, action dim) and equal."""
    obs = {k: v[None] for k, v in frame.items() if k.startswith("observation.")}
    actions = []
    for policy in policies:
        policy.eval()
        policy.reset()
        torch.manual_seed(0)
        with torch.no_grad():
            actions.append(post(policy.select_action(pre(dict(obs)))))
    assert actions[0].shape == (1, frame["action"].shape[-1]) and torch.isfinite(actions[0]).all()
    for other in actions[1:]:
        torch.testing.assert_close(actions[0], other)
