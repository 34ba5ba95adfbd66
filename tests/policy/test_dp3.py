"""``dp3``: 3D Diffusion Policy as a LeRobot policy, LeRobot's diffusion U-Net on focal's point-cloud encoder.

Real policies, real LeRobot code, no mocks:
  * DP3's defaults (chunking, DDIM 10, sample prediction, EMA) and the type's registration and config errors;
  * the loss's gradient reaches the point-cloud encoder and the state MLP, through a condition of
    n_obs · (cloud + state widths), and a camera the dataset also holds builds nothing;
  * ``select_action`` acts with the EMA copy, 10 U-Net calls per chunk of ``n_action_steps`` actions;
  * a dataset without a cloud (or a state) is refused, naming what is missing and the fix;
  * the processor normalises the cloud as focal's does (per channel, from per-slot statistics);
  * ``lerobot-train --policy.type=dp3`` runs as a subprocess on a tiny on-disk dataset with point clouds, and the
    checkpoint reloads through ``make_policy`` / ``from_pretrained`` and acts.
"""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.factory import get_policy_class, make_pre_post_processors
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_focal.config_errors import ConfigError
from lerobot_focal.constants import OBS_POINTCLOUD
from lerobot_focal.datasets.making.synthetic import SyntheticSpec, write_synthetic_dataset
from lerobot_focal.policy.dp3 import DP3Config, DP3Policy
from tests.policy.test_diffusion_ema import (
    TINY_DIFFUSION_ARGS,
    last_checkpoint,
    parted_and_counted,
    tiny_train_run,
)
from tests.policy.test_diffusion_fco import reload_and_act

STATE, POINTS, ACT, B = 9, 32, 3, 4  # the synthetic dataset's state and action
CLOUD_DIM, STATE_DIM, EMBED = 16, 8, 16
IMAGE = "observation.images.front"


def _config(**overrides) -> DP3Config:
    """A tiny dp3 on the synthetic dataset's features, plus a camera it must not read."""
    inputs = {
        OBS_STATE: PolicyFeature(FeatureType.STATE, (STATE,)),
        OBS_POINTCLOUD: PolicyFeature(FeatureType.STATE, (POINTS, 3)),
        IMAGE: PolicyFeature(FeatureType.VISUAL, (3, 32, 32)),
    }
    kwargs = dict(
        device="cpu", down_dims=(16, 32), kernel_size=3, n_groups=4, diffusion_step_embed_dim=EMBED,
        pointcloud_feature_dim=CLOUD_DIM, state_feature_dim=STATE_DIM, input_features=inputs,
        output_features={ACTION: PolicyFeature(FeatureType.ACTION, (ACT,))},
    )
    return DP3Config(**{**kwargs, **overrides})


def _batch(seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        OBS_STATE: torch.rand(B, 2, STATE, generator=g) * 2 - 1,
        OBS_POINTCLOUD: torch.rand(B, 2, POINTS, 3, generator=g) * 2 - 1,
        ACTION: torch.rand(B, 16, ACT, generator=g) * 2 - 1,
        "action_is_pad": torch.zeros(B, 16, dtype=torch.bool),
    }


def test_defaults_are_dp3s_and_the_type_is_registered():
    cfg = DP3Config()
    assert (cfg.n_obs_steps, cfg.horizon, cfg.n_action_steps, cfg.drop_n_last_frames) == (2, 16, 8, 7)
    assert (cfg.noise_scheduler_type, cfg.num_inference_steps, cfg.prediction_type) == ("DDIM", 10, "sample")
    assert cfg.use_ema and cfg.use_ema_for_inference
    assert (cfg.pointcloud_feature_dim, cfg.state_feature_dim, cfg.use_pointcloud_color) == (64, 64, False)
    assert "dp3" in PreTrainedConfig.get_known_choices() and get_policy_class("dp3") is DP3Policy
    # LeRobot checks issubclass(cfg.__class__, <annotation of __init__'s config>): the class, not a string.
    assert inspect.signature(DP3Policy.__init__).parameters["config"].annotation is DP3Config
    # The parent's checks speak under dp3's own label: the user typed --policy.type=dp3.
    for bad, message in ((dict(ema_power=0.0), "ema_power must be a number > 0"),
                         (dict(pointcloud_feature_dim=0), "pointcloud_feature_dim must be a number > 0"),
                         (dict(use_ema=False), "use_ema_for_inference=true needs use_ema=true")):
        with pytest.raises(ConfigError, match=f"^--policy.type=dp3: {message}") as error:
            DP3Config(**bad)
        assert "diffusion_ema" not in str(error.value)


def test_the_loss_trains_the_cloud_encoder_through_a_condition_of_both_widths():
    torch.manual_seed(0)
    policy = DP3Policy(_config())
    model = policy.diffusion
    cond = 2 * (CLOUD_DIM + STATE_DIM)  # n_obs_steps · (cloud + state features), as DP3 joins them
    assert model.obs_encoder.global_cond_dim == cond
    assert model.unet.mid_modules[0].cond_encoder[1].in_features == EMBED + cond
    assert not any("rgb" in name for name, _ in policy.named_modules())  # the camera builds no encoder
    loss, _ = policy.forward(_batch())
    loss.backward()
    assert torch.isfinite(loss)
    for name in ("obs_encoder.pointcloud.point_mlp.0.weight", "obs_encoder.pointcloud.projection.0.weight",
                 "obs_encoder.state.net.0.weight", "unet.final_conv.1.weight"):
        grad = model.get_parameter(name).grad
        assert grad is not None and grad.abs().sum() > 0, name
    assert {id(p) for p in policy.get_optim_params()} == {id(p) for p in model.parameters()}
    assert not any(p.requires_grad for p in policy.ema_diffusion.parameters())


def test_select_action_acts_with_the_ema_copy_at_ten_unet_calls_per_chunk():
    policy = DP3Policy(_config())
    calls = parted_and_counted(policy)
    obs = {k: v[:1, -1] for k, v in _batch().items() if k.startswith("observation.")}
    with torch.no_grad():
        actions = [policy.select_action(dict(obs)) for _ in range(policy.config.n_action_steps)]
        assert calls == {"online": 0, "ema": 10}  # one chunk: DDIM's 10 steps, all on the EMA network
        policy.select_action(dict(obs))
    assert calls == {"online": 0, "ema": 20}  # the 9th action starts the next chunk
    assert actions[0].shape == (1, ACT) and all(torch.isfinite(a).all() for a in actions)
    assert policy._modules["diffusion"] is not policy.ema_diffusion  # the online network is back in place


@pytest.mark.parametrize(("drop", "extra", "missing"), [
    (OBS_POINTCLOUD, {}, OBS_POINTCLOUD),
    (OBS_STATE, {}, OBS_STATE),
    (None, {"use_env_state": True}, "observation.environment_state"),
])
def test_a_dataset_without_what_dp3_reads_is_refused_with_the_fix(drop, extra, missing):
    cfg = _config(**extra)
    cfg.input_features.pop(drop, None)
    with pytest.raises(ValueError, match=rf"dp3 conditions on .* has no \['{missing}'\].*Fix: .*diffusion_ema"):
        DP3Policy(cfg)


def test_a_cloud_of_the_wrong_shape_is_refused():
    cfg = _config()
    cfg.input_features[OBS_POINTCLOUD] = PolicyFeature(FeatureType.STATE, (POINTS, 4))
    with pytest.raises(ValueError, match=r"must have shape \(num_points, 3\)"):
        DP3Policy(cfg)


def test_the_processor_normalises_the_cloud_per_channel_as_focals_does():
    """Per-point-slot statistics are pooled per channel, a state dimension constant in the data keeps a unit
    scale, and the camera the policy does not read needs no statistics."""
    cfg = _config()
    lo, hi = torch.tensor([-1.0, -2.0, 0.0]), torch.tensor([1.0, 2.0, 4.0])
    slot_lo = lo.expand(POINTS, 3).clone()
    slot_lo[1:] += 0.5  # only slot 0 reaches the minimum: pooled, the minimum is still lo
    state_lo, state_hi = -torch.ones(STATE), torch.ones(STATE)
    state_hi[0] = state_lo[0] = 0.25  # constant in the data
    stats = {OBS_POINTCLOUD: {"min": slot_lo, "max": hi.expand(POINTS, 3).clone()},
             OBS_STATE: {"min": state_lo, "max": state_hi},
             ACTION: {"min": -torch.ones(ACT), "max": torch.ones(ACT)}}
    pre, _ = make_pre_post_processors(cfg, dataset_stats=stats)  # resolved by LeRobot's naming convention
    cloud = lo + torch.rand(POINTS, 3) * (hi - lo)
    state = torch.zeros(STATE)
    out = pre({OBS_POINTCLOUD: cloud[None], OBS_STATE: state, IMAGE: torch.rand(3, 32, 32)})
    torch.testing.assert_close(out[OBS_POINTCLOUD][0], (cloud - lo) / (hi - lo) * 2 - 1)
    assert out[OBS_STATE][0, 0].item() == pytest.approx(-0.25)  # (x − value), not scaled by 1e8
    # Built with the dataset (make_policy), the policy adapts the statistics in place, as focal does: LeRobot hands
    # that very dict to a fine-tuned checkpoint's normaliser, past this processor factory.
    DP3Policy(cfg, dataset_stats=stats)
    torch.testing.assert_close(stats[OBS_POINTCLOUD]["min"], lo)


# ----------------------------------------------------------------------------------------------- lerobot-train

STEPS = 4
REPO_ID = "local/dp3_tiny"


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("dp3")
    root, out = tmp / "dataset", tmp / "run"
    # With a camera too: dp3 reads the cloud and the state only, whatever else the dataset holds.
    spec = SyntheticSpec(num_episodes=2, episode_length=24, num_points=POINTS, with_image=True, image_size=32)
    write_synthetic_dataset(root, spec, REPO_ID)
    policy_args = [
        "--policy.type=dp3",
        *TINY_DIFFUSION_ARGS,  # the U-Net of _config()
        f"--policy.pointcloud_feature_dim={CLOUD_DIM}",
        f"--policy.state_feature_dim={STATE_DIM}",
    ]
    tiny_train_run(policy_args, root, REPO_ID, out, STEPS)
    return root, out


@pytest.mark.subprocess
def test_lerobot_train_dp3_on_point_clouds_reloads_and_acts(trained):
    root, out = trained
    model_dir, saved, weights = last_checkpoint(out, STEPS)
    assert saved["type"] == "dp3" and saved["use_ema"] is True and saved["num_inference_steps"] == 10
    assert (saved["pointcloud_feature_dim"], saved["state_feature_dim"], saved["horizon"]) == (CLOUD_DIM, STATE_DIM, 16)
    assert {OBS_POINTCLOUD, OBS_STATE, IMAGE} <= set(saved["input_features"])
    assert "ema_diffusion.obs_encoder.pointcloud.point_mlp.0.weight" in weights  # the EMA holds the encoder too
    assert not any("rgb" in k for k in weights)
    for policy in reload_and_act(model_dir, root, REPO_ID, DP3Policy):
        assert int(policy.ema_step) == STEPS
