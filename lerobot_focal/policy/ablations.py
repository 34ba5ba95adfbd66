"""The paper's method switches and its ablations as data: which fields an ablation sets, and how a config's
unset switches are filled.

In `FocalConfig` the method switches default to None, meaning "not given": `resolve_method_switches` fills them
from the ablation, else from the paper's value. So a switch given on the command line is known to be given even
when it equals the paper's value, and contradicting an ablation is an error instead of being silently overridden.
"""

from __future__ import annotations

from typing import Any

#: The method switches an ablation may set, with the paper's values.
PAPER_METHOD: dict[str, object] = {
    "objective": "fco",
    "anchor_sampler": "logit_normal",
    "anchor_mu": 4.0,
    "anchor_sigma": 1.6,
    "fixed_r": 1.0,
    "time_loss_window": "proximal",
    "time_weight": 1.0,
    "regularizer": "freq",
    "freq_loss_window": "macro",
    "freq_band": "all",
    "consistency_target": "ema",
}

# The paper's ablations, each a set of field values (Tables 4, 9 and the appendix). Applying one is
# equivalent to passing those fields on the command line.
ABLATIONS: dict[str, dict[str, object]] = {
    "wo_las": {"anchor_sampler": "adjacent"},
    "wo_fco_las": {"objective": "flowpolicy", "anchor_sampler": "adjacent"},
    "time_only_fco": {"regularizer": "time_mse"},
    "freq_only_fco": {"time_weight": 0.0},
    "fixed_r": {"anchor_sampler": "fixed", "fixed_r": 1.0},
    "fco_full_macro": {"time_loss_window": "macro"},
    "fco_prox_freq": {"time_loss_window": "macro", "freq_loss_window": "proximal"},
    "low_freq_only": {"freq_band": "low"},
    "high_freq_only": {"freq_band": "high"},
    "anchor_0.4_0.5": {"anchor_mu": 0.4, "anchor_sigma": 0.5},
    "anchor_1.4_0.5": {"anchor_mu": 1.4, "anchor_sigma": 0.5},
    # Not a paper ablation: what the authors' public code does (mixture anchor, online stop-grad target).
    "public_code": {"anchor_sampler": "mixture", "consistency_target": "online"},
}

assert set(PAPER_METHOD) >= {k for fields in ABLATIONS.values() for k in fields}


def resolve_method_switches(config: Any, error: type[Exception] = ValueError) -> None:
    """Fill each method switch of `config` left unset (None) from its ablation, else from the paper's value.

    A switch that was given and contradicts the ablation is an error, even when it equals the paper's value
    (`ablation=wo_las anchor_sampler=logit_normal` asks for two different samplers). A given value equal to
    the ablation's is accepted: that is what a saved config.json holds, so checkpoints load back.
    """
    ablation: dict[str, object] = {}
    if config.ablation is not None:
        if config.ablation not in ABLATIONS:
            raise error(f"Unknown ablation {config.ablation!r}. Choose one of {sorted(ABLATIONS)} or leave it unset.")
        ablation = ABLATIONS[config.ablation]
    conflicts = [
        f"{name}={getattr(config, name)!r} (the ablation sets {name}={value!r})"
        for name, value in ablation.items()
        if getattr(config, name) is not None and getattr(config, name) != value
    ]
    if conflicts:
        raise error(
            f"ablation={config.ablation!r} conflicts with the switch(es) also given: {'; '.join(conflicts)}. "
            "An ablation sets these itself: drop the switch, or drop the ablation and give every switch."
        )
    for name, paper_value in PAPER_METHOD.items():
        if getattr(config, name) is None:
            setattr(config, name, ablation.get(name, paper_value))
