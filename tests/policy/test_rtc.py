"""focal's side of LeRobot's real-time chunking (lerobot_focal/policy/rtc.py): the guided step in focal's time
convention, against LeRobot's own `RTCProcessor`, and what `lerobot-rollout --inference.type=rtc` asks of a policy."""

from __future__ import annotations

import pytest
import torch
from lerobot.configs import RTCAttentionSchedule
from lerobot.policies.rtc.configuration_rtc import RTCConfig
from lerobot.policies.rtc.modeling_rtc import RTCProcessor
from lerobot.rollout.inference.rtc import supports_rtc_inference

from lerobot_focal.policy.rtc import FocalRTC, committed_length, guidance_weight, guided_euler_step

from .helpers import small_policy

L, D = 12, 3  # focal's default macro-trajectory: N·H = 3·4 steps


def _policy(rtc: RTCConfig | None = None, **kw):
    torch.manual_seed(0)
    policy = small_policy(pointcloud=None, state=5, action=D, **kw).eval()
    policy.config.rtc_config = rtc
    policy.init_rtc_processor()  # what lerobot-rollout does after setting the config
    return policy


def _obs():
    return {"observation.state": torch.linspace(-0.5, 0.5, 5).view(1, 5)}


def _noise(seed: int = 1) -> torch.Tensor:
    return torch.randn((1, L, D), generator=torch.Generator().manual_seed(seed))


def test_lerobot_rollout_accepts_focal_for_rtc():
    policy = _policy()
    assert policy.supports_rtc()
    assert supports_rtc_inference(policy)  # LeRobot's own check: supports_rtc() and the call shape


@pytest.mark.parametrize("tau", [0.0, 0.01, 0.1, 0.3, 0.5, 0.7, 0.95])
def test_guided_step_is_lerobots_rtc_step_under_the_time_mapping(tau):
    """LeRobot's RTCProcessor at its time t = 1 − τ, on the velocity field v_lerobot = −v_focal, gives minus
    focal's guided velocity (dt small enough that the overshoot cap does not act)."""
    torch.manual_seed(3)
    x = torch.randn(2, L, D)
    prev = torch.randn(2, 8, D)
    a = torch.randn(L, D)

    def v_focal(m):  # any smooth field of the sample
        return a - 0.7 * m + 0.1 * m**2

    cfg = RTCConfig(execution_horizon=8, max_guidance_weight=10.0)
    lerobot = RTCProcessor(cfg).denoise_step(
        x_t=x, prev_chunk_left_over=prev, inference_delay=3, time=1.0 - tau,
        original_denoise_step_partial=lambda m: -v_focal(m),
    )
    focal = FocalRTC(cfg)
    target, weights, delay, horizon = focal.prefix(prev, 3, None, tuple(x.shape), x.device, x.dtype)
    assert (delay, horizon) == (3, 8)
    dt = 0.01
    x_next, info = guided_euler_step(x, v_focal(x), tau, dt, target, weights, cfg.max_guidance_weight)
    assert info["gain"] < 1.0
    torch.testing.assert_close((x_next - x) / dt, -lerobot, atol=2e-3, rtol=1e-4)


def test_guidance_weight_is_clipped_and_vanishes_at_the_data_end():
    assert guidance_weight(0.0, 10.0) == 10.0
    assert guidance_weight(0.01, 10.0) == 10.0  # ((0.99)² + 0.01²) / (0.01·0.99) ≈ 99, clipped
    assert guidance_weight(0.5, 10.0) == pytest.approx(2.0)
    assert guidance_weight(1.0, 10.0) == 0.0
    assert guidance_weight(0.5, 0.0) == 0.0


def test_zero_guidance_weight_is_the_unguided_step():
    torch.manual_seed(0)
    x, v, target = torch.randn(1, L, D), torch.randn(1, L, D), torch.randn(1, L, D)
    weights = torch.ones(1, L, 1)
    for tau, dt in ((0.01, 0.99), (0.3, 0.2)):
        x_next, info = guided_euler_step(x, v, tau, dt, target, weights, max_guidance_weight=0.0)
        assert info["gain"] == 0.0
        assert torch.equal(x_next, x + dt * v)


def test_zero_weights_over_the_chunk_give_the_unguided_chunk():
    """ZEROS schedule at delay 0: every weight is 0, so the guided chunk is bit for bit the unguided one."""
    policy = _policy(RTCConfig(prefix_attention_schedule=RTCAttentionSchedule.ZEROS, execution_horizon=8))
    unguided = policy.predict_action_chunk(_obs(), noise=_noise())
    guided = policy.predict_action_chunk(_obs(), noise=_noise(), inference_delay=0,
                                         prev_chunk_left_over=torch.randn(8, D))
    assert torch.equal(guided, unguided)


@pytest.mark.parametrize("steps", [1, 3])
def test_a_full_mask_over_the_prefix_reproduces_it_closer_than_unguided(steps):
    """ONES schedule: weight 1 over the leftover's first execution_horizon actions. One network evaluation
    reproduces them (the capped one-step guidance is the blend with W = 1); with Euler steps the guided chunk
    is closer to them than the unguided one is."""
    rtc = RTCConfig(prefix_attention_schedule=RTCAttentionSchedule.ONES, execution_horizon=6)
    policy = _policy(rtc, num_inference_steps=steps)
    prev = torch.randn((8, D), generator=torch.Generator().manual_seed(7))
    unguided = policy.predict_action_chunk(_obs(), noise=_noise())
    guided = policy.predict_action_chunk(_obs(), noise=_noise(), inference_delay=2, prev_chunk_left_over=prev)
    assert guided.shape == unguided.shape == (1, L, D)  # RTC chunks are the whole macro-trajectory
    err_guided = (guided[0, :6] - prev[:6]).abs().max()
    err_unguided = (unguided[0, :6] - prev[:6]).abs().max()
    assert err_guided < 0.5 * err_unguided
    if steps == 1:
        assert err_guided < 1e-5
        torch.testing.assert_close(guided[0, 6:], unguided[0, 6:])  # weight 0 past the horizon: untouched


def test_one_step_guidance_is_the_soft_masked_blend():
    """Default LINEAR schedule, one NFE: (1 − W)·M̂ + W·Y with LeRobot's prefix weights; β < 1/(1 − ε) blends
    that fraction of it."""
    prev = torch.randn((8, D), generator=torch.Generator().manual_seed(5))
    for beta, gain in ((10.0, 1.0), (0.5, 0.5 * 0.99)):
        rtc = RTCConfig(execution_horizon=8, max_guidance_weight=beta)
        policy = _policy(rtc)
        unguided = policy.predict_action_chunk(_obs(), noise=_noise())[0]
        guided = policy.predict_action_chunk(_obs(), noise=_noise(), inference_delay=2, prev_chunk_left_over=prev)[0]
        w = RTCProcessor(rtc).get_prefix_weights(2, 8, L).view(L, 1)
        target = torch.cat([prev, torch.zeros(L - 8, D)])
        torch.testing.assert_close(guided, unguided + gain * w * (target - unguided), atol=1e-5, rtol=1e-5)


def test_engine_padding_rows_are_not_guided_towards():
    """LeRobot's engine pads a short leftover with zero rows up to execution_horizon: those rows are not
    actions, so the guided chunk past the real leftover is the unguided one."""
    rtc = RTCConfig(prefix_attention_schedule=RTCAttentionSchedule.ONES, execution_horizon=8)
    policy = _policy(rtc)
    real = torch.randn((3, D), generator=torch.Generator().manual_seed(2))
    padded = torch.cat([real, torch.zeros(5, D)])
    assert committed_length(padded.unsqueeze(0)) == 3
    unguided = policy.predict_action_chunk(_obs(), noise=_noise())
    guided = policy.predict_action_chunk(_obs(), noise=_noise(), inference_delay=1, prev_chunk_left_over=padded)
    torch.testing.assert_close(guided[0, :3], real, atol=1e-5, rtol=0)
    torch.testing.assert_close(guided[0, 3:], unguided[0, 3:])
    # An all-padding leftover (nothing committed) is the unguided chunk.
    none = policy.predict_action_chunk(_obs(), noise=_noise(), inference_delay=1,
                                       prev_chunk_left_over=torch.zeros(8, D))
    assert torch.equal(none, unguided)


def test_batched_leftovers_guide_each_sample():
    policy = _policy(RTCConfig(prefix_attention_schedule=RTCAttentionSchedule.ONES, execution_horizon=4))
    obs = {"observation.state": torch.randn(2, 5)}
    prev = torch.randn(2, 6, D)
    out = policy.predict_action_chunk(obs, noise=torch.randn(2, L, D), inference_delay=1, prev_chunk_left_over=prev)
    torch.testing.assert_close(out[:, :4], prev[:, :4], atol=1e-5, rtol=0)


def test_a_leftover_of_the_wrong_shape_is_refused_with_its_shape():
    policy = _policy(RTCConfig())
    with pytest.raises(ValueError, match=r"prev_chunk_left_over has shape \(8, 5\).*\(T, 3\)"):
        policy.predict_action_chunk(_obs(), inference_delay=1, prev_chunk_left_over=torch.randn(8, 5))


def test_without_rtc_nothing_changes_and_select_action_still_steps_through_h_actions():
    policy = _policy()
    assert policy.rtc_processor is None
    chunk = policy.predict_action_chunk(_obs(), noise=_noise())
    assert chunk.shape == (1, 4, D)
    # The RTC keywords are ignored when RTC is off (LeRobot's sync engine never passes them).
    same = policy.predict_action_chunk(_obs(), noise=_noise(), inference_delay=2, prev_chunk_left_over=torch.ones(8, D))
    assert torch.equal(chunk, same)
    # With RTC on, select_action (lerobot-eval) still executes the proximal H actions of each chunk.
    policy = _policy(RTCConfig())
    policy.reset()
    actions = [policy.select_action(_obs()) for _ in range(5)]
    assert all(a.shape == (1, D) for a in actions)
    assert len(policy._queues["action"]) == 3  # second chunk: 4 queued, one popped


def test_a_checkpoint_saved_with_rtc_settings_loads_them(tmp_path):
    policy = _policy(RTCConfig(execution_horizon=6, max_guidance_weight=3.0))
    policy.save_pretrained(tmp_path)
    loaded = type(policy).from_pretrained(tmp_path)
    assert loaded.config.rtc_config.execution_horizon == 6
    assert loaded.rtc_processor is not None and loaded.rtc_processor.config.max_guidance_weight == 3.0
