"""Real-time chunking (RTC) for focal: LeRobot's guided inpainting of the committed prefix, in focal's time.

``lerobot-rollout --inference.type=rtc`` computes the next chunk while the arm executes the current one and
passes the previous chunk's unexecuted actions (``prev_chunk_left_over``, Y) and the steps the computation takes
(``inference_delay``). The prefix weights W (1 over the delay, then falling to 0 at ``execution_horizon``) are
LeRobot's own schedules (``RTCProcessor.get_prefix_weights``). LeRobot's step is written for t: 1 (noise) -> 0;
focal's τ = 1 − t goes from ε (noise) to 1, with v_focal = −v_LeRobot. In focal's terms a guided Euler step is

    M̂_1 = M_τ + (1 − τ)·v,   M_{τ+Δτ} = M_τ + Δτ·v + min(1, Δτ·w(τ))·W⊙(Y − M̂_1),
    w(τ) = min(β, ((1 − τ)² + τ²) / (τ(1 − τ))),

LeRobot's guidance (identity Jacobian, as in its ``RTCProcessor``: no backward pass) with the fraction of the
error a step removes capped at 1. With focal's single consistency step (τ = ε -> 1) and β ≥ 1/(1 − ε) that is
the soft-masked blend (1 − W)⊙M̂ + W⊙Y; with ``num_inference_steps > 1`` it acts on every Euler step. The
mapping table, the choice and the engine's quirks (zero padding of the leftover, one observation per chunk,
delay ≥ 1): docs/rtc.md.
"""

from __future__ import annotations

import logging

import torch
from lerobot.policies.rtc.configuration_rtc import RTCConfig
from lerobot.policies.rtc.modeling_rtc import RTCProcessor
from torch import Tensor

logger = logging.getLogger(__name__)


def rtc_active(config) -> bool:
    """Whether the policy config carries an enabled RTC config (set by ``lerobot-rollout --inference.type=rtc``)."""
    rtc = getattr(config, "rtc_config", None)
    return rtc is not None and bool(rtc.enabled)


def guidance_weight(tau: float, max_guidance_weight: float) -> float:
    """RTC's guidance weight at focal's time τ, clipped at β: min(β, ((1−τ)² + τ²) / (τ(1−τ))).

    LeRobot's ``RTCProcessor`` computes the same function of its ``tau = 1 − time``: β at the noise end
    (τ → 0), 0 at the data end (τ = 1, where it is nan and ``nan_to_num`` makes it 0)."""
    if tau >= 1.0:
        return 0.0
    if tau <= 0.0:
        return float(max_guidance_weight)
    return float(min(max_guidance_weight, ((1.0 - tau) ** 2 + tau**2) / (tau * (1.0 - tau))))


def guided_euler_step(x: Tensor, v: Tensor, tau: float, dt: float, target: Tensor, weights: Tensor,
                      max_guidance_weight: float) -> tuple[Tensor, dict]:
    """One Euler step of focal's flow from τ to τ + dt with RTC's prefix guidance.

    ``x``: M_τ (B, L, d); ``v``: the network's velocity there; ``target``: Y (B or 1, L, d); ``weights``: W
    broadcastable to x. Returns M_{τ+dt} and what LeRobot's debug tracker records. With a zero guidance weight
    the step is the unguided ``x + dt·v``."""
    w = guidance_weight(tau, max_guidance_weight)
    gain = min(dt * w, 1.0)  # fraction of the prefix error this step removes; > 1 would overshoot
    if gain <= 0.0:
        return x + dt * v, {"guidance_weight": w, "gain": 0.0}
    x1 = x + (1.0 - tau) * v  # the flow's estimate of the data from here
    err = weights * (target - x1)
    return x + dt * v + gain * err, {"guidance_weight": w, "gain": gain, "x1_t": x1, "err": err}


def committed_length(prev: Tensor) -> int:
    """Rows of a (B, T, d) leftover before the engine's trailing all-zero padding rows."""
    nonzero = (prev != 0).flatten(start_dim=2).any(dim=2).any(dim=0)  # (T,)
    idx = torch.nonzero(nonzero)
    return int(idx[-1]) + 1 if len(idx) else 0


class FocalRTC:
    """focal's side of LeRobot's RTC: builds the prefix target and weights, and runs the guided steps.

    Holds a LeRobot ``RTCProcessor`` for what is LeRobot's (the prefix-weight schedules, the debug tracker of
    ``--inference.rtc.debug=true``); the guided step itself is :func:`guided_euler_step`."""

    def __init__(self, rtc_config: RTCConfig):
        self.config = rtc_config
        self.processor = RTCProcessor(rtc_config)
        self.guided_chunks = 0

    def prefix(self, prev_chunk_left_over: Tensor, inference_delay: int | None, execution_horizon: int | None,
               shape: tuple[int, int, int], device, dtype) -> tuple[Tensor, Tensor, int, int] | None:
        """(Y, W, delay, horizon) for a chunk of ``shape`` (B, L, d), or None when there is nothing to continue."""
        b, length, dim = shape
        prev = prev_chunk_left_over.to(device=device, dtype=dtype)
        if prev.ndim == 2:
            prev = prev.unsqueeze(0)
        if prev.ndim != 3 or prev.shape[2] != dim or prev.shape[0] not in (1, b):
            raise ValueError(
                f"prev_chunk_left_over has shape {tuple(prev_chunk_left_over.shape)}; focal continues chunks of "
                f"shape (B={b}, L={length}, d={dim}) and expects (T, {dim}) or ({b}, T, {dim}) normalised actions "
                "(the previous chunk's unexecuted part, as LeRobot's RTC engine passes it)."
            )
        n = min(committed_length(prev), length)
        if n == 0:
            return None
        horizon = min(int(execution_horizon or self.config.execution_horizon), n)
        delay = max(0, min(int(inference_delay or 0), horizon))
        weights = self.processor.get_prefix_weights(delay, horizon, length).to(device=device, dtype=dtype)
        target = torch.zeros((prev.shape[0], length, dim), device=device, dtype=dtype)
        target[:, :n] = prev[:, :n]
        return target, weights.view(1, length, 1), delay, horizon

    def sample(self, x: Tensor, times: Tensor, velocity, prev_chunk_left_over: Tensor | None,
               inference_delay: int | None, execution_horizon: int | None) -> Tensor | None:
        """Integrate focal's flow along ``times`` (τ_0 = ε … 1) from ``x``, guided towards the leftover prefix;
        None without a leftover to continue (the first chunk: the caller integrates unguided).

        ``velocity(m, i)`` evaluates the network at times[i]."""
        if prev_chunk_left_over is None:
            return None
        prefix = self.prefix(prev_chunk_left_over, inference_delay, execution_horizon, tuple(x.shape), x.device,
                             x.dtype)
        if prefix is None:
            return None
        steps = len(times) - 1
        target, weights, delay, horizon = prefix
        beta = float(self.config.max_guidance_weight)
        for i in range(steps):
            tau, dt = float(times[i]), float(times[i + 1] - times[i])
            x, info = guided_euler_step(x, velocity(x, i), tau, dt, target, weights, beta)
            if self.processor.is_debug_enabled():
                # LeRobot's tracker is keyed by LeRobot's time (1 − τ), so its plots read as for pi0.
                self.processor.track(time=1.0 - tau, x_t=x, x1_t=info.get("x1_t"), err=info.get("err"),
                                     weights=weights, guidance_weight=info["guidance_weight"],
                                     inference_delay=delay, execution_horizon=horizon)
        self.guided_chunks += 1
        if self.guided_chunks == 1:
            logger.info(
                "focal RTC: chunk guided by the previous chunk's %d committed actions (delay %d, execution horizon "
                "%d, %s weights, max guidance weight %g, %d network evaluation(s))",
                int(committed_length(target)), delay, horizon, self.config.prefix_attention_schedule.value, beta,
                steps,
            )
        return x
