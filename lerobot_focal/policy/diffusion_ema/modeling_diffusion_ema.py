"""``diffusion_ema``: LeRobot's ``DiffusionPolicy`` trained as LeRobot trains it, evaluated with EMA weights.

Diffusion Policy and DP3 keep an exponential moving average of the denoising network (observation encoder and
U-Net) and evaluate it; LeRobot 0.6.1's ``diffusion`` does not. This policy adds exactly that and nothing else:

  * ``ema_diffusion``: a frozen copy of LeRobot's ``DiffusionModel`` (``self.diffusion``), a submodule, so
    LeRobot's own ``save_pretrained`` / ``from_pretrained`` / ``--resume`` / ``lerobot-eval`` carry it, with
    the buffer ``ema_step`` (updates so far) that keeps the schedule across a resume;
  * ``update()``: called by ``lerobot-train`` after every optimizer step, moves the copy towards the online
    weights with DP3's decay 1 − (1 + s)^−0.75 clipped to 0.9999 (``lerobot_focal.policy.ema``, the same code
    as focal's EMA);
  * inference (``select_action`` / ``predict_action_chunk``) runs LeRobot's own sampling on the EMA copy.

Training (the loss, the optimizer's parameters, the noise scheduler) is LeRobot's ``DiffusionPolicy``, unchanged.
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
from torch import Tensor

from lerobot_focal.policy.diffusion_ema.configuration_diffusion_ema import DiffusionEmaConfig
from lerobot_focal.policy.ema import ema_decay, ema_update_, frozen_copy


class DiffusionEmaPolicy(DiffusionPolicy):
    """LeRobot's ``DiffusionPolicy`` plus an EMA copy of its ``DiffusionModel``, used to act."""

    config_class = DiffusionEmaConfig
    name = "diffusion_ema"

    def __init__(self, config: DiffusionEmaConfig, **kwargs: Any):
        super().__init__(config, **kwargs)
        self.init_ema()

    def init_ema(self) -> None:
        """The EMA copy of ``self.diffusion``; a subclass that builds its own network (``dp3``) calls it after."""
        self.ema_diffusion = frozen_copy(self.diffusion) if self.config.use_ema else None
        # Number of EMA updates so far; a buffer so checkpoints and --resume keep the EMA schedule.
        self.register_buffer("ema_step", torch.zeros((), dtype=torch.long))

    def train(self, mode: bool = True) -> DiffusionEmaPolicy:
        super().train(mode)
        if self.ema_diffusion is not None:
            self.ema_diffusion.eval()  # the inference network never runs in training mode
        return self

    @torch.no_grad()
    def update(self) -> None:
        """Advance the EMA weights by one step (LeRobot calls this after every optimizer step)."""
        if self.ema_diffusion is None:
            return
        cfg = self.config
        decay = ema_decay(int(self.ema_step), power=cfg.ema_power, min_decay=cfg.ema_min_decay,
                          max_decay=cfg.ema_max_decay, update_after_step=cfg.ema_update_after_step)
        ema_update_(self.ema_diffusion, self.diffusion, decay)
        self.ema_step += 1

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """LeRobot's ``predict_action_chunk`` with the EMA network in the place of the online one.

        ``DiffusionPolicy.predict_action_chunk`` samples with ``self.diffusion``; for the duration of the call that
        name points at the EMA copy (LeRobot's queue handling and sampling code run unchanged), then back.
        """
        if self.ema_diffusion is None or not self.config.use_ema_for_inference:
            return super().predict_action_chunk(batch, noise=noise)
        online = self._modules["diffusion"]
        self._modules["diffusion"] = self.ema_diffusion
        try:
            return super().predict_action_chunk(batch, noise=noise)
        finally:
            self._modules["diffusion"] = online
