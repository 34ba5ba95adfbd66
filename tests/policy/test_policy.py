"""FocalPolicy's contract with LeRobot: NFE per chunk, queues, save/load, EMA, and clear errors on bad input."""

import copy

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_focal.policy import FocalConfig, FocalPolicy
from lerobot_focal.policy.configuration_focal import FocalConfigError
from lerobot_focal.policy.encoders import PointCloudEncoder
from lerobot_focal.policy.method_groups import AnchorConfig, LossConfig
from lerobot_focal.policy.modeling_focal import ema_decay

from .helpers import small_config, small_policy


def _obs(b=2, n_obs=None, state=9, points=64):
    shape = (b,) if n_obs is None else (b, n_obs)
    return {
        "observation.state": torch.randn(*shape, state),
        "observation.pointcloud": torch.randn(*shape, points, 3),
    }


def _train_batch(b=4, cfg=None):
    batch = _obs(b, n_obs=2)
    batch["action"] = torch.randn(b, 12, 3)
    return batch


def test_one_network_evaluation_per_executed_chunk():
    policy = small_policy().eval()
    calls = []
    policy.ema_model.velocity_net.register_forward_hook(lambda *a: calls.append(1))
    policy.model.velocity_net.register_forward_hook(lambda *a: calls.append(1))
    policy.reset()
    for _ in range(3 * policy.config.n_action_steps):
        action = policy.select_action(_obs(b=1))
        assert action.shape == (1, 3)
    assert len(calls) == 3  # 12 actions, H = 4 → 3 chunks → 3 evaluations


def test_multi_step_inference_is_an_option_with_k_evaluations():
    policy = small_policy(num_inference_steps=3).eval()
    calls = []
    policy.ema_model.velocity_net.register_forward_hook(lambda *a: calls.append(1))
    policy.predict_action_chunk(_obs(b=1))
    assert len(calls) == 3


def test_executed_chunk_is_the_first_h_steps_of_the_macro_trajectory():
    policy = small_policy().eval()
    noise, current = torch.randn(1, 12, 3), _obs(b=1)
    obs = {k: v.unsqueeze(1).expand(-1, 2, *v.shape[1:]) for k, v in current.items()}
    full = policy.sample_macro_trajectory(obs, noise=noise)
    chunk = policy.predict_action_chunk(current, noise=noise)
    torch.testing.assert_close(chunk, full[:, :4])


def test_executing_into_the_foresight_part_replans_less_and_executes_the_macro_trajectory_in_order():
    """n_action_steps > H (LeRobot's usual knob): 8 of L = 12 actions per evaluation, in the predicted order."""
    policy = small_policy(n_action_steps=8).eval()
    calls = []
    policy.ema_model.velocity_net.register_forward_hook(lambda *a: calls.append(1))
    noise, current = torch.randn(1, 12, 3), _obs(b=1)
    obs = {k: v.unsqueeze(1).expand(-1, 2, *v.shape[1:]) for k, v in current.items()}
    full = policy.sample_macro_trajectory(obs, noise=noise)
    calls.clear()
    policy.reset()
    executed = [policy.select_action(current, noise=noise) for _ in range(16)]
    assert len(calls) == 2  # steps 0 and 8
    torch.testing.assert_close(torch.stack(executed[:8], dim=1), full[:, :8])
    assert small_policy().config.n_action_steps == 4  # unset: the proximal chunk, as the paper
    with pytest.raises(FocalConfigError, match="n_action_steps=13 must be between 1 and the macro horizon L"):
        small_config(n_action_steps=13)


def test_inference_noise_scale_is_a_sampling_temperature():
    """Scale 0 starts every chunk from M_0 = 0: the same observation gives the same chunk; scale 1 does not."""
    current = _obs(b=1)
    cold, warm = small_policy(inference_noise_scale=0.0).eval(), small_policy().eval()
    warm.load_state_dict(cold.state_dict())
    torch.testing.assert_close(cold.predict_action_chunk(current), cold.predict_action_chunk(current))
    torch.testing.assert_close(cold.predict_action_chunk(current),
                               warm.predict_action_chunk(current, noise=torch.zeros(1, 12, 3)))
    assert not torch.allclose(warm.predict_action_chunk(current), warm.predict_action_chunk(current))
    with pytest.raises(FocalConfigError, match="inference_noise_scale must be a finite number"):
        small_config(inference_noise_scale=-1.0)


def test_save_and_reload_give_identical_actions(tmp_path):
    policy = small_policy()
    opt = torch.optim.AdamW(policy.get_optim_params(), lr=1e-3)
    for _ in range(3):
        loss, _ = policy.forward(_train_batch())
        opt.zero_grad()
        loss.backward()
        opt.step()
        policy.update()
    policy.eval()
    policy.save_pretrained(tmp_path)
    loaded = FocalPolicy.from_pretrained(tmp_path).eval()
    assert int(loaded.ema_step) == 3
    obs, noise = _obs(b=3), torch.randn(3, 12, 3)
    torch.testing.assert_close(policy.predict_action_chunk(obs, noise=noise),
                               loaded.predict_action_chunk(obs, noise=noise))
    for (k, a), (_, b) in zip(policy.state_dict().items(), loaded.state_dict().items(), strict=True):
        torch.testing.assert_close(a, b, msg=k)


def test_ema_update_arithmetic():
    policy = small_policy()
    p_online = next(policy.model.parameters())
    p_ema = next(policy.ema_model.parameters())
    assert not p_ema.requires_grad
    assert all(p is not q for p in policy.get_optim_params() for q in policy.ema_model.parameters())
    with torch.no_grad():
        p_online.add_(1.0)
    policy.update()  # first updates copy (decay 0)
    torch.testing.assert_close(p_ema, p_online)
    policy.update()
    for step in range(2, 6):
        before_ema, online = p_ema.clone(), p_online.clone().add_(0.5)
        with torch.no_grad():
            p_online.copy_(online)
        decay = ema_decay(step, power=0.75, min_decay=0.0, max_decay=0.9999)
        assert decay == pytest.approx(1 - (1 + step - 1) ** -0.75)
        policy.update()
        torch.testing.assert_close(p_ema, decay * before_ema + (1 - decay) * online)
    assert ema_decay(10**9, power=0.75, min_decay=0.0, max_decay=0.9999) == 0.9999


def test_online_target_does_not_touch_ema_in_forward_and_ema_target_does():
    for target, expect_ema in (("online", False), ("ema", True)):
        policy = small_policy(consistency_target=target, anchor=AnchorConfig(kind="fixed", fixed_r=0.9))
        calls = []
        policy.ema_model.velocity_net.register_forward_hook(lambda *a, calls=calls: calls.append(1))
        policy.forward(_train_batch())
        assert bool(calls) == expect_ema


def test_forward_returns_the_loss_parts_for_logging():
    _, logs = small_policy().forward(_train_batch())
    assert set(logs) == {"loss_time", "loss_freq"} and all(isinstance(v, float) for v in logs.values())


def test_extra_dataset_features_are_ignored():
    cfg = small_config()
    cfg.input_features["observation.environment_state"] = PolicyFeature(FeatureType.ENV, (39,))
    cfg.input_features["observation.images.depth"] = PolicyFeature(FeatureType.VISUAL, (1, 32, 32))
    policy = FocalPolicy(cfg)
    assert policy.config.used_observation_keys == ["observation.pointcloud", "observation.state"]


def test_preprocessor_leaves_unused_inputs_such_as_uint16_depth_alone():
    """A robot observation with a raw uint16 depth map passes the preprocessor (LeRobot's default normaliser
    would try to normalise it in place and fail) and the used keys are normalised."""
    from lerobot_focal.policy import make_focal_pre_post_processors

    cfg = small_config(pointcloud=None)
    cfg.input_features["observation.images.depth"] = PolicyFeature(FeatureType.VISUAL, (1, 8, 8))
    stats = {
        "observation.state": {"min": torch.zeros(9), "max": torch.full((9,), 2.0)},
        "observation.images.depth": {"mean": torch.tensor([[[1000.0]]]), "std": torch.tensor([[[10.0]]])},
        "action": {"min": torch.zeros(3), "max": torch.ones(3)},
    }
    pre, _ = make_focal_pre_post_processors(cfg, dataset_stats=stats)
    depth = torch.full((1, 8, 8), 60000, dtype=torch.uint16)
    out = pre({"observation.state": torch.ones(9), "observation.images.depth": depth})
    torch.testing.assert_close(out["observation.state"], torch.zeros(1, 9))  # min-max to [-1, 1]: 1 → 0
    assert out["observation.images.depth"].dtype == torch.uint16
    assert out["observation.images.depth"].to(torch.int32).max().item() == 60000


def test_environment_state_is_min_max_normalised_and_constant_dimensions_keep_a_unit_scale(tmp_path):
    """observation.environment_state is normalised like the state; a dimension that never moves in the demos
    (here dim 1) is shifted to 0 and left unscaled instead of being divided by LeRobot's 1e-8 fallback, and the
    saved preprocessor reloads with the same statistics (what lerobot-eval uses)."""
    from lerobot.processor import PolicyProcessorPipeline

    from lerobot_focal.policy import make_focal_pre_post_processors

    cfg = small_config(pointcloud=None, use_env_state=True)
    cfg.input_features["observation.environment_state"] = PolicyFeature(FeatureType.ENV, (3,))
    stats = {
        "observation.state": {"min": torch.zeros(9), "max": torch.full((9,), 2.0)},
        "observation.environment_state": {"min": torch.tensor([0.0, 0.7, -1.0]), "max": torch.tensor([4.0, 0.7, 1.0])},
        "action": {"min": torch.zeros(3), "max": torch.tensor([1.0, 1.0, 0.0])},  # action dim 2 constant too
    }
    pre, post = make_focal_pre_post_processors(cfg, dataset_stats=stats)
    obs = {"observation.state": torch.ones(9), "observation.environment_state": torch.tensor([2.0, 1.2, 0.5])}
    out = pre(dict(obs))
    torch.testing.assert_close(out["observation.environment_state"], torch.tensor([[0.0, 0.5, 0.5]]))
    action = post(torch.tensor([[0.0, 0.0, 0.25]]))
    torch.testing.assert_close(action, torch.tensor([[0.5, 0.5, 0.25]]))  # constant dim: value + output
    pre.save_pretrained(tmp_path)
    reloaded = PolicyProcessorPipeline.from_pretrained(tmp_path, config_filename="policy_preprocessor.json")
    torch.testing.assert_close(reloaded(dict(obs))["observation.environment_state"], torch.tensor([[0.0, 0.5, 0.5]]))


def test_image_only_policy_trains_and_acts():
    policy = small_policy(state=None, pointcloud=None, image=(3, 32, 32))
    batch = {"observation.images.front": torch.rand(2, 2, 3, 32, 32), "action": torch.randn(2, 12, 3)}
    loss, _ = policy.forward(batch)
    loss.backward()
    assert policy.eval().select_action({"observation.images.front": torch.rand(1, 3, 32, 32)}).shape == (1, 3)


@pytest.mark.parametrize(("n_action_steps", "n_chunks"), [(4, 3), (1, 4)])
def test_rgb_frames_are_encoded_once_each_with_the_actions_of_whole_window_encoding(n_action_steps, n_chunks):
    """select_action encodes each camera frame once, on the step it arrives (when the next chunk will read it),
    and the actions equal those of encoding the whole n_obs_steps window at the chunk step."""
    torch.manual_seed(0)
    policy = small_policy(state=4, pointcloud=None, image=(3, 32, 40), crop_shape=(28, 36),
                          chunk_size=n_action_steps, n_chunks=n_chunks).eval()
    encoder = policy._inference_net().obs_encoder.rgb[0]
    encoded: list[int] = []
    encoder.register_forward_hook(lambda module, args, out: encoded.append(args[0].shape[0]))
    frames = [{"observation.state": torch.randn(1, 4), "observation.images.front": torch.rand(1, 3, 32, 40)}
              for _ in range(9)]
    horizon = policy.config.horizon
    noises = [torch.randn(1, horizon, 3) for _ in range(9)]
    per_step_encodes, actions = [], []
    for t, obs in enumerate(frames):
        before = sum(encoded)
        actions.append(policy.select_action(dict(obs), noise=noises[t]))
        per_step_encodes.append(sum(encoded) - before)

    reference = FocalPolicy(policy.config)
    reference.load_state_dict(policy.state_dict())
    reference.eval()
    for t in range(0, 9, n_action_steps):
        window = [frames[max(t - 1, 0)], frames[t]]
        obs = {k: torch.stack([w[k] for w in window], dim=1) for k in frames[0]}
        chunk = reference.sample_macro_trajectory(obs, noises[t])[:, :n_action_steps]
        for i in range(n_action_steps):
            if t + i < 9:
                torch.testing.assert_close(actions[t + i], chunk[:, i], rtol=1e-5, atol=1e-5)
    if n_action_steps == 4:
        # chunk steps 0, 4, 8: the first encodes its window (two copies of frame 0), the later ones only their
        # own frame; steps 3 and 7 encode theirs ahead; the other steps encode nothing.
        assert per_step_encodes == [2, 0, 0, 1, 1, 0, 0, 1, 1]
    else:
        assert per_step_encodes == [2] + [1] * 8
    policy.reset()
    policy.select_action(dict(frames[0]))
    assert len(policy._frame_features) == policy.config.n_obs_steps


def test_pointcloud_encoder_in_place_relus_give_the_out_of_place_outputs_and_gradients():
    """The point MLP's ReLUs overwrite their LayerNorm's output (a CPU speed-up): autograd must still see the
    values it saved, so outputs and every gradient equal those of out-of-place ReLUs bit for bit."""
    torch.manual_seed(0)
    encoder = PointCloudEncoder()
    reference = copy.deepcopy(encoder)
    relus = [m for m in reference.modules() if isinstance(m, torch.nn.ReLU)]
    assert len(relus) == 3 and all(m.inplace for m in relus)
    for m in relus:
        m.inplace = False
    points = torch.randn(4, 2, 256, 3)
    outputs = []
    for net in (encoder, reference):
        out = net(points)
        (out.square() * torch.linspace(0, 1, out.shape[-1])).sum().backward()
        outputs.append(out)
    assert torch.equal(outputs[0], outputs[1])
    for (name, a), b in zip(encoder.named_parameters(), reference.parameters(), strict=True):
        assert a.grad is not None and torch.equal(a.grad, b.grad), name


def test_pointcloud_encoder_trains_on_the_max_pool_winners_with_the_dense_outputs_and_gradients():
    """With gradients, the point MLP runs on the points that hold some channel's maximum only (each cloud padded
    to the largest winner count): the pooled features and every gradient are those of running it on all points,
    up to the float rounding of a different summation order, and without gradients nothing changes."""
    torch.manual_seed(0)
    encoder = PointCloudEncoder()
    dense = copy.deepcopy(encoder)
    dense.winners_only_backward = False
    # Clouds of different spreads have different winner counts: the padding is exercised.
    points = torch.randn(3, 2, 512, 3) * torch.tensor([0.1, 1.0, 10.0]).view(3, 1, 1, 1)
    winners = encoder._max_winners(points)
    assert winners.shape[:2] == (3, 2) and 0 < winners.shape[2] < 512 / 2
    outputs = []
    for net in (encoder, dense):
        out = net(points)
        (out.square() * torch.linspace(0, 1, out.shape[-1])).sum().backward()
        outputs.append(out)
    torch.testing.assert_close(outputs[0], outputs[1], rtol=1e-6, atol=1e-6)
    for (name, a), b in zip(encoder.named_parameters(), dense.parameters(), strict=True):
        assert a.grad is not None and a.grad.abs().sum() > 0, name
        torch.testing.assert_close(a.grad, b.grad, rtol=1e-4, atol=1e-6, msg=name)
    with torch.no_grad():
        assert torch.equal(encoder(points), dense(points))


# --- bad input --------------------------------------------------------------------------------------------


def test_no_usable_observation_names_what_is_needed():
    with pytest.raises(ValueError, match=r"no observation it can use.*observation.environment_state"):
        cfg = small_config(state=None, pointcloud=None)
        cfg.input_features["observation.environment_state"] = PolicyFeature(FeatureType.ENV, (39,))
        FocalPolicy(cfg)


def test_bad_pointcloud_shape():
    with pytest.raises(ValueError, match=r"num_points, 3"):
        small_policy(pointcloud=(64, 4))


def test_horizon_the_unet_cannot_take():
    with pytest.raises(FocalConfigError, match=r"multiple of 4.*L = 5·2 = 10"):
        FocalConfig(chunk_size=5, n_chunks=2)


def test_mismatched_batch_shapes_and_missing_keys():
    policy = small_policy()
    bad = _train_batch()
    bad["observation.state"] = torch.randn(4, 2, 7)
    with pytest.raises(ValueError, match=r"'observation.state' has shape \(4, 2, 7\)"):
        policy.forward(bad)
    short = _train_batch()
    short["action"] = torch.randn(4, 8, 3)
    with pytest.raises(ValueError, match=r"L=12"):
        policy.forward(short)
    missing = _train_batch()
    del missing["observation.pointcloud"]
    with pytest.raises(KeyError, match="observation.pointcloud"):
        policy.forward(missing)


def test_nan_in_a_batch_is_refused_with_its_key():
    policy = small_policy()
    batch = _train_batch()
    batch["action"][0, 3, 1] = float("nan")
    with pytest.raises(ValueError, match=r"'action' contains 1 NaN"):
        policy.forward(batch)
    obs = _obs(b=1)
    obs["observation.state"][0, 0] = float("inf")
    with pytest.raises(ValueError, match="observation.state"):
        policy.eval().select_action(obs)


def test_bad_method_switches():
    with pytest.raises(FocalConfigError, match="consistency_target"):
        FocalConfig(consistency_target="teacher")
    with pytest.raises(FocalConfigError, match="use_ema"):
        FocalConfig(use_ema=False)
    with pytest.raises(FocalConfigError, match="loss.freq_band"):
        FocalConfig(loss=LossConfig(freq_band="mid"))


def test_a_cloud_policy_acts_on_clouds_of_another_size_and_refuses_other_channels():
    """DP3 trains on 1024 points and evaluates on 512; the max-pooled encoder takes any count. A policy trained on
    64-point clouds acts on 32- and 128-point ones through its own preprocessor (the same action for a cloud
    whose extra points repeat its own), and still refuses a cloud with other channels, naming the shape."""
    from lerobot_focal.policy import make_focal_pre_post_processors

    cfg = small_config()
    stats = {
        "observation.state": {"min": -torch.ones(9), "max": torch.ones(9)},
        "observation.pointcloud": {"min": -torch.ones(64, 3), "max": torch.ones(64, 3)},
        "action": {"min": -torch.ones(3), "max": torch.ones(3)},
    }
    policy = FocalPolicy(cfg, dataset_stats=stats).eval()
    cfg.inference_noise_scale = 0.0  # deterministic chunks: the same observation gives the same action
    pre, _ = make_focal_pre_post_processors(cfg, dataset_stats=stats)
    state, cloud = torch.rand(9), torch.rand(1, 32, 3)  # a batched cloud, as the env's processor step gives it
    actions = []
    for points in (cloud, cloud.repeat(1, 4, 1)):  # 32 points, and 128 made of the same 32 (the same max-pool)
        policy.reset()
        actions.append(policy.select_action(pre({"observation.state": state, "observation.pointcloud": points})))
    torch.testing.assert_close(actions[0], actions[1])
    with pytest.raises(ValueError, match=r"'observation.pointcloud' has shape \(1, 32, 6\).*trained on \(P, 3\)"):
        pre({"observation.state": state, "observation.pointcloud": torch.rand(1, 32, 6)})
