"""The method's two groups of knobs in `FocalConfig`: how (τ, r) are drawn (`anchor`) and the loss (`loss`).

On the command line they are ``--policy.anchor.*`` and ``--policy.loss.*``, as LeRobot's own policies nest a
group (``rtc_config``). Their field names are those of the validated specs the model uses
(`time_samplers.TimeSamplerSpec`, `objective.ObjectiveSpec`), so one new knob is one field here and one there.

A switch an ablation may set (`ablations.PAPER_METHOD`) defaults to None, "not given", and is filled from the
ablation or the paper when the config is built; the others carry the paper's value.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


@dataclass
class AnchorConfig:
    """Where the flow time τ and the consistency anchor r are drawn (Locally Anchored Sampling by default).

    Args:
        kind: "logit_normal" (LAS), "adjacent" (FlowPolicy's r = τ + Δ), "fixed" or "mixture" (the authors'
            public code).
        eps: ε: τ ~ U[ε, 1], and inference starts from time ε.
        mu: μ_r of LAS's logit-normal anchor.
        sigma: σ_r of LAS's logit-normal anchor.
        adjacent_delta: Δ of the adjacent sampler (and of FlowPolicy's velocity mask).
        fixed_r: r of the fixed sampler.
        mixture_mu_a: μ of the second logit-normal of the public code's mixture sampler.
        mixture_sigma_a: σ of that logit-normal.
        mixture_ratio: Probability of taking the smaller of the two draws in the mixture sampler.
    """

    kind: str | None = None
    eps: float = 0.01
    mu: float | None = None
    sigma: float | None = None
    adjacent_delta: float = 0.01
    fixed_r: float | None = None
    mixture_mu_a: float = 0.6
    mixture_sigma_a: float = 1.6
    mixture_ratio: float = 0.15

    def values(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class LossConfig:
    """The training loss: the Foresight Composite Objective by default, FlowPolicy's as the "w/o FCO" ablation.

    Args:
        kind: "fco" (FocalPolicy) or "flowpolicy" (FlowPolicy's segment-wise consistency flow matching).
        time_window: Where L_time acts: "proximal" (the executed chunk) or "macro" (all L steps).
        time_weight: Weight of L_time (0 gives the L_freq-only ablation).
        regularizer: The macro-trajectory term: "freq" (L_freq), "time_mse" (time-domain MSE) or "none".
        freq_window: Where L_freq acts: "macro" or "proximal".
        freq_weight: λ, the weight of L_freq.
        freq_band: DCT band L_freq sees: "all", "low" or "high".
        freq_cutoff: First "high" DCT coefficient; None → half the L_freq window.
        macro_mse_weight: Weight of the "time_mse" regulariser.
        cfm_num_segments: Segments of FlowPolicy's objective.
        cfm_boundary: Anchors at or past this use the exact interpolant at the segment end (FlowPolicy).
        cfm_alpha: Weight of FlowPolicy's velocity-consistency term.
    """

    kind: str | None = None
    time_window: str | None = None
    time_weight: float | None = None
    regularizer: str | None = None
    freq_window: str | None = None
    freq_weight: float = 1e-4
    freq_band: str | None = None
    freq_cutoff: int | None = None
    macro_mse_weight: float = 1.0
    cfm_num_segments: int = 2
    cfm_boundary: float = 1.0
    cfm_alpha: float = 1e-5

    def values(self) -> dict[str, Any]:
        return asdict(self)


#: Flat keys of configs saved before these groups existed → (group, field) (see `saved_config_upgrade`).
MOVED_METHOD_FIELDS: dict[str, tuple[str, str]] = {
    "objective": ("loss", "kind"),
    "time_loss_window": ("loss", "time_window"),
    "freq_loss_window": ("loss", "freq_window"),
    **{name: ("loss", name) for name in ("time_weight", "regularizer", "freq_weight", "freq_band", "freq_cutoff",
                                         "macro_mse_weight", "cfm_num_segments", "cfm_boundary", "cfm_alpha")},
    "anchor_sampler": ("anchor", "kind"),
    "time_eps": ("anchor", "eps"),
    "anchor_mu": ("anchor", "mu"),
    "anchor_sigma": ("anchor", "sigma"),
    **{name: ("anchor", name) for name in ("adjacent_delta", "fixed_r", "mixture_mu_a", "mixture_sigma_a",
                                           "mixture_ratio")},
}
