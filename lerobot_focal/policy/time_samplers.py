"""Flow-time samplers: the flow time τ and the consistency anchor r of each training sample.

Convention (the paper's, opposite to LeRobot's pi0 family): τ = 0 is noise, τ = 1 is data.

The sampler is what separates FocalPolicy's Locally Anchored Sampling (LAS) from FlowPolicy's adjacent-time
consistency: LAS draws r from a logit-normal centred near the terminal time, so the target
f_θ⁻(M_r, r) ≈ M_1 is nearly the expert trajectory itself and carries a strong, low-variance signal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lerobot_focal.config_errors import require_in_range, require_positive

ANCHOR_SAMPLERS = ("logit_normal", "adjacent", "fixed", "mixture")


@dataclass(frozen=True)
class TimeSamplerSpec:
    """Everything that decides how (τ, r) are drawn; built from `FocalConfig.anchor` (the same field names)."""

    kind: str = "logit_normal"
    eps: float = 0.01
    # LAS (paper): r = sigmoid(mu + sigma * xi).
    mu: float = 4.0
    sigma: float = 1.6
    # w/o LAS (FlowPolicy): r = min(τ + delta, 1).
    adjacent_delta: float = 0.01
    # Fixed-r ablation: r = fixed_r (the paper's ablation uses 1).
    fixed_r: float = 1.0
    # The authors' public code ("v0" mixture): a = σ(mu_a + sigma_a ξ₁), b = σ(mu + sigma ξ₂);
    # r = max(a, b) with probability 1 - mixture_ratio, else min(a, b).
    mixture_mu_a: float = 0.6
    mixture_sigma_a: float = 1.6
    mixture_ratio: float = 0.15

    def __post_init__(self) -> None:
        if self.kind not in ANCHOR_SAMPLERS:
            raise ValueError(
                f"Unknown anchor sampler {self.kind!r}. Choose one of {list(ANCHOR_SAMPLERS)} "
                "(logit_normal = LAS, adjacent = FlowPolicy / 'w/o LAS', fixed = 'fixed r', "
                "mixture = the authors' public code)."
            )
        require_in_range("anchor.eps", self.eps, 0.0, 1.0, high_open=True)
        require_positive(**{"anchor.sigma": self.sigma, "anchor.mixture_sigma_a": self.mixture_sigma_a})
        for name, mu in (("anchor.mu", self.mu), ("anchor.mixture_mu_a", self.mixture_mu_a)):
            if not math.isfinite(mu):
                raise ValueError(f"{name} must be a finite number, got {mu}.")
        require_in_range("anchor.fixed_r", self.fixed_r, 0.0, 1.0)
        require_in_range("anchor.adjacent_delta", self.adjacent_delta, 0.0, 1.0, low_open=True,
                         why="r = min(τ + Δ, 1) must lie past τ.")
        require_in_range("anchor.mixture_ratio", self.mixture_ratio, 0.0, 1.0, why="It is a probability.")


def sample_flow_time(batch_size: int, eps: float, *, device=None, generator=None) -> Tensor:
    """τ ~ U[eps, 1]; eps keeps τ away from pure noise, where f = M_τ + (1-τ)v has no signal."""
    u = torch.rand(batch_size, device=device, generator=generator)
    return eps + (1.0 - eps) * u


def sample_anchor_time(
    spec: TimeSamplerSpec, tau: Tensor, *, generator: torch.Generator | None = None
) -> Tensor:
    """Draw the anchor r for each τ according to `spec.kind`."""
    shape, device = tau.shape, tau.device
    if spec.kind == "logit_normal":
        xi = torch.randn(shape, device=device, generator=generator)
        return torch.sigmoid(spec.mu + spec.sigma * xi)
    if spec.kind == "adjacent":
        return torch.clamp(tau + spec.adjacent_delta, max=1.0)
    if spec.kind == "fixed":
        return torch.full(shape, spec.fixed_r, device=device, dtype=tau.dtype)
    # mixture
    a = torch.sigmoid(spec.mixture_mu_a + spec.mixture_sigma_a * torch.randn(shape, device=device, generator=generator))
    b = torch.sigmoid(spec.mu + spec.sigma * torch.randn(shape, device=device, generator=generator))
    take_min = torch.rand(shape, device=device, generator=generator) < spec.mixture_ratio
    return torch.where(take_min, torch.minimum(a, b), torch.maximum(a, b))


def sample_times(
    spec: TimeSamplerSpec, batch_size: int, *, device=None, generator: torch.Generator | None = None
) -> tuple[Tensor, Tensor]:
    """Return (τ, r), each of shape (batch_size,)."""
    tau = sample_flow_time(batch_size, spec.eps, device=device, generator=generator)
    return tau, sample_anchor_time(spec, tau, generator=generator)
