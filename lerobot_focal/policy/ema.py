"""The EMA copy of a network on DP3's schedule, shared by `focal` and `diffusion_ema`.

DP3 (and Diffusion Policy before it) keeps an exponential moving average of the weights, updated after every
optimizer step with a decay that warms up as 1 − (1 + s)^−power (power 0.75) and is clipped to a maximum of
0.9999, and evaluates those EMA weights. The copy is a frozen submodule of the policy, so LeRobot's own
`save_pretrained` / `from_pretrained` / `--resume` carry it, together with a step-count buffer.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

from lerobot_focal.config_errors import require_non_negative, require_positive


def ema_decay(step: int, *, power: float, min_decay: float, max_decay: float, update_after_step: int = 0) -> float:
    """DP3's EMA warm-up: 0 for the first updates, then 1 − (1 + s)^−power clipped to [min, max]."""
    s = max(0, step - update_after_step - 1)
    if s <= 0:
        return 0.0
    return max(min_decay, min(1.0 - (1.0 + s) ** -power, max_decay))


def check_ema_settings(config) -> None:
    """The EMA fields both policies' configs share (ema_power, ema_min/max_decay, ema_update_after_step); a
    ValueError names the field and the valid range."""
    require_positive(ema_power=config.ema_power)
    require_non_negative(ema_update_after_step=config.ema_update_after_step)
    lo, hi = config.ema_min_decay, config.ema_max_decay
    if not (0.0 <= lo <= hi < 1.0 and hi > 0.0):  # also refuses NaN
        raise ValueError(
            f"EMA decays must satisfy 0 ≤ ema_min_decay ≤ ema_max_decay < 1 with ema_max_decay > 0 (got {lo}, {hi}; "
            "DP3's are 0 and 0.9999)."
        )


def frozen_copy(module: nn.Module) -> nn.Module:
    """The EMA network's initial state: a copy of `module` without gradients, in eval mode."""
    return copy.deepcopy(module).requires_grad_(False).eval()


@torch.no_grad()
def ema_update_(ema: nn.Module, online: nn.Module, decay: float) -> None:
    """ema ← decay·ema + (1 − decay)·online for the parameters (a plain copy at decay 0); buffers (e.g.
    BatchNorm statistics) are copied, not averaged."""
    ema_params = list(ema.parameters())
    online_params = list(online.parameters())
    if decay == 0.0:
        torch._foreach_copy_(ema_params, online_params)
    else:
        torch._foreach_lerp_(ema_params, online_params, 1.0 - decay)
    for ema_buf, buf in zip(ema.buffers(), online.buffers(), strict=True):
        ema_buf.copy_(buf)
