"""`focal_adamw`: LeRobot's AdamW with PyTorch's fused kernel where every parameter allows it.

The CPU benchmark networks are small, so a training step is dominated by per-tensor overhead, and the default
(for-loop) AdamW update is ~15 % of it; the fused update does the same arithmetic in one kernel per step
(measured with `python -m lerobot_focal.benchmarks.train_step`). It is a registered LeRobot optimizer type so a
checkpoint's `train_config.json` names it and `--resume` rebuilds the same optimizer; its state dict is plain
AdamW's, so the optimizer state of a run started with `adamw` loads into it too.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from lerobot.optim import AdamWConfig
from lerobot.optim.optimizers import OptimizerConfig

from lerobot_focal.config_errors import check_adamw, reports_config_errors


def fused_supported(params: list) -> bool:
    """Fused AdamW needs floating-point parameters on one device type that has the kernel (CPU, CUDA, MPS)."""
    tensors = [p for group in params for p in (group["params"] if isinstance(group, dict) else [group])]
    if not tensors:
        return False
    kinds = {t.device.type for t in tensors}
    return len(kinds) == 1 and kinds <= {"cpu", "cuda", "mps"} and all(t.is_floating_point() for t in tensors)


@OptimizerConfig.register_subclass("focal_adamw")
@reports_config_errors("--optimizer.type=focal_adamw")
@dataclass
class FusedAdamWConfig(AdamWConfig):
    # None: fused when the parameters allow it (see `fused_supported`), else LeRobot's default AdamW.
    fused: bool | None = None

    def __post_init__(self) -> None:
        check_adamw(lr=self.lr, betas=self.betas, eps=self.eps, weight_decay=self.weight_decay,
                    grad_clip_norm=self.grad_clip_norm)

    def build(self, params) -> torch.optim.Optimizer:
        params = list(params)
        kwargs = asdict(self)
        kwargs.pop("grad_clip_norm")
        fused = kwargs.pop("fused")
        if fused is None:
            fused = fused_supported(params)
        return torch.optim.AdamW(params, fused=fused or None, **kwargs)
