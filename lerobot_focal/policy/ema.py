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


def ema_decay(step: int, *, power: float, min_decay: float, max_decay: float, update_after_step: int = 0) -> float:
    """DP3's EMA warm-up: 0 for the first updates, then 1 − (1 + s)^−power clipped to [min, max]."""
    s = max(0, step - update_after_step - 1)
    if s <= 0:
        return 0.0
    return max(min_decay, min(1.0 - (1.0 + s) ** -power, max_decay))


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
