"""The paper's method switches and its ablations as data: which fields an ablation sets, and how a config's
unset switches are filled.

In `FocalConfig` the method switches default to None, meaning "not given": `resolve_method_switches` fills them
from the ablation, else from the paper's value. So a switch given on the command line is known to be given even
when it equals the paper's value, and contradicting an ablation is an error instead of being silently overridden.
"""

from __future__ import annotations

from typing import Any

#: The method switches an ablation may set (a dotted path in `FocalConfig`), with the paper's values.
PAPER_METHOD: dict[str, object] = {
    "loss.kind": "fco",
    "anchor.kind": "logit_normal",
    "anchor.mu": 4.0,
    "anchor.sigma": 1.6,
    "anchor.fixed_r": 1.0,
    "loss.time_window": "proximal",
    "loss.time_weight": 1.0,
    "loss.regularizer": "freq",
    "loss.freq_window": "macro",
    "loss.freq_band": "all",
    "consistency_target": "ema",
}

# The paper's ablations, each a set of field values (Tables 4, 9 and the appendix). Applying one is
# equivalent to passing those fields on the command line (`--policy.anchor.kind=adjacent`, …).
ABLATIONS: dict[str, dict[str, object]] = {
    "wo_las": {"anchor.kind": "adjacent"},
    "wo_fco_las": {"loss.kind": "flowpolicy", "anchor.kind": "adjacent"},
    "time_only_fco": {"loss.regularizer": "time_mse"},
    "freq_only_fco": {"loss.time_weight": 0.0},
    "fixed_r": {"anchor.kind": "fixed", "anchor.fixed_r": 1.0},
    "fco_full_macro": {"loss.time_window": "macro"},
    "fco_prox_freq": {"loss.time_window": "macro", "loss.freq_window": "proximal"},
    "low_freq_only": {"loss.freq_band": "low"},
    "high_freq_only": {"loss.freq_band": "high"},
    "anchor_0.4_0.5": {"anchor.mu": 0.4, "anchor.sigma": 0.5},
    "anchor_1.4_0.5": {"anchor.mu": 1.4, "anchor.sigma": 0.5},
    # Not a paper ablation: what the authors' public code does (mixture anchor, online stop-grad target).
    "public_code": {"anchor.kind": "mixture", "consistency_target": "online"},
}

assert set(PAPER_METHOD) >= {k for fields in ABLATIONS.values() for k in fields}


def get_switch(config: Any, path: str) -> Any:
    """The value of a dotted switch path ("anchor.kind") of `config`."""
    obj = config
    for name in path.split("."):
        obj = getattr(obj, name)
    return obj


def set_switch(config: Any, path: str, value: Any) -> None:
    *groups, name = path.split(".")
    obj = config
    for group in groups:
        obj = getattr(obj, group)
    setattr(obj, name, value)


def resolve_method_switches(config: Any, error: type[Exception] = ValueError) -> None:
    """Fill each method switch of `config` left unset (None) from its ablation, else from the paper's value.

    A switch that was given and contradicts the ablation is an error, even when it equals the paper's value
    (`ablation=wo_las anchor.kind=logit_normal` asks for two different samplers). A given value equal to
    the ablation's is accepted: that is what a saved config.json holds, so checkpoints load back.
    """
    ablation: dict[str, object] = {}
    if config.ablation is not None:
        if config.ablation not in ABLATIONS:
            raise error(f"Unknown ablation {config.ablation!r}. Choose one of {sorted(ABLATIONS)} or leave it unset.")
        ablation = ABLATIONS[config.ablation]
    conflicts = [
        f"{path}={get_switch(config, path)!r} (the ablation sets {path}={value!r})"
        for path, value in ablation.items()
        if get_switch(config, path) is not None and get_switch(config, path) != value
    ]
    if conflicts:
        raise error(
            f"ablation={config.ablation!r} conflicts with the switch(es) also given: {'; '.join(conflicts)}. "
            "An ablation sets these itself: drop the switch, or drop the ablation and give every switch."
        )
    for path, paper_value in PAPER_METHOD.items():
        if get_switch(config, path) is None:
            set_switch(config, path, ablation.get(path, paper_value))
