"""``diffusion_fco``: LeRobot's ``DiffusionPolicy`` with the Foresight Composite Objective (paper Table 2, "w. FCO").

The paper (Table 2 and the appendix "Module Generalizability setups") adds FCO to a diffusion policy (DP3):
"we apply the frequency-domain loss to DP3's 16-step predicted trajectory, while applying the time-domain loss
on the 8-step execution chunk". FCO itself is paper Eq. (4.3)/(4.10): L_FCO = L_time + λ·L_freq, λ = 1e-4,
L_freq on orthonormal-DCT coefficients. This module applies it to LeRobot's own ``diffusion`` policy without
copying it: the network, the noise scheduler, the standard loss and inference (DDPM/DDIM with
``num_inference_steps``) are LeRobot's, unchanged.

Loss (one batch; a = expert actions of the horizon, normalised as LeRobot's diffusion sees them):

    L = L_DP + L_FCO(x̂0)                                      (L_DP dropped if fco_keep_diffusion_loss=False)
    L_DP   = LeRobot's DiffusionModel.compute_loss, unchanged  (mean MSE of ε̂ vs ε, or of x̂ vs a)
    L_FCO  = w_time · L_time + λ · L_freq                      (lerobot_focal.policy.objective.composite_loss)
    L_time = mean over the executed window × d of (x̂0 − a)²  — per sample, then batch mean
    L_freq = sum over the horizon × d of (DCT(x̂0) − DCT(a))²  — per sample, then batch mean

with the executed window = steps [n_obs_steps−1, n_obs_steps−1+n_action_steps) of the horizon: exactly the
actions ``select_action`` executes (supervised window = executed window, as in focal). The reductions (mean for
L_time, sum for L_freq) are the ones of our FCO implementation, which λ = 1e-4 is calibrated for.

x̂0, the clean-trajectory estimate, is recovered from the same network call that produced L_DP (captured with a
forward hook on the U-Net, so L_DP, its noise and its timesteps are bit-for-bit LeRobot's), with the
scheduler's own ᾱ_t = ``noise_scheduler.alphas_cumprod[t]``, exactly as DDPM/DDIM ``step()`` computes its
``pred_original_sample``:

    epsilon prediction:  x̂0 = (x_t − √(1−ᾱ_t)·ε̂) / √ᾱ_t          sample prediction:  x̂0 = x̂

and, when ``clip_sample`` and ``fco_clip_x0`` are on, clamped to ±``clip_sample_range`` as ``step()`` does.
With ε-prediction each sample's FCO is weighted by min(SNR_t, γ) (``fco_weighting="min_snr"``, see below).

Choices where the paper is silent or ambiguous (each is a config field):
  * Target of L_time. In FocalPolicy L_time is a consistency loss against a target network; a diffusion policy
    has none, and for DP3 the paper's "time-domain loss" is DP3's own regression to the expert actions. So here
    L_time regresses x̂0 onto the expert actions on the executed chunk.
  * L_DP is kept and FCO is added on top (``fco_keep_diffusion_loss=True``, default): the paper presents FCO as
    a module added to existing chunking policies, and with LeRobot's default ε-prediction the ε-MSE is the
    denoising objective itself. With ``prediction_type="sample"`` (DP3's setting) and
    ``fco_keep_diffusion_loss=False`` the loss is literally the paper's: time-domain loss on the execution chunk
    plus λ·frequency-domain loss on the predicted trajectory.
  * Clamping x̂0 (``fco_clip_x0=True``). With ε-prediction x̂0 amplifies the ε error by √((1−ᾱ_t)/ᾱ_t), about
    2·10³ at the last step of the default ``squaredcos_cap_v2`` schedule; the clamp is what inference applies to
    the same quantity and keeps the FCO term bounded (elements outside the range get no FCO gradient).
  * Weighting (``fco_weighting``, ε-prediction only). x̂0 − a = (ε − ε̂)/√SNR_t, so an unweighted FCO term is
    an ε-loss reweighted by 1/SNR_t: 50 at t = 90 and 4·10⁶ at t = 99 of the default 100-step schedule. The
    noisiest steps then dominate the gradient and crowd out the denoising objective FCO is added to
    (docs/benchmarks.md shows it on the plateau grid: a higher ε-loss and lower success than plain DP).
    Min-SNR-γ weighting (Hang et al., 2023), min(SNR_t, γ), is the standard cure for x̂0 losses: it caps each
    step's weight at the ε-loss's, so FCO adds its window and frequency emphasis without outweighing the
    denoising. ``"none"`` keeps the unweighted term.
  * Padding. With ``do_mask_loss_for_padding`` the copy-padded steps (``action_is_pad``) get zero FCO error
    (x̂0 is replaced by the target there); without it, as LeRobot's loss, they are supervised like the rest.
  * Defaults otherwise are ``DiffusionConfig``'s, so "DP" and "DP w. FCO" differ only in the loss; set the
    same ``horizon`` / ``n_action_steps`` / ``prediction_type`` flags for both (the paper's DP3: 16 / 8 / sample).
"""

from typing import Any

import torch
from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
from lerobot.utils.constants import ACTION
from torch import Tensor

from lerobot_focal.policy.diffusion_fco.configuration_diffusion_fco import DiffusionFcoConfig
from lerobot_focal.policy.objective import ObjectiveSpec, composite_loss


class DiffusionFcoPolicy(DiffusionPolicy):
    """LeRobot's ``DiffusionPolicy`` whose training loss adds FCO on the clean-sample estimate x̂0."""

    config_class = DiffusionFcoConfig
    name = "diffusion_fco"

    def __init__(self, config: DiffusionFcoConfig, **kwargs: Any):
        super().__init__(config, **kwargs)
        # Both specs act on pre-sliced windows ("macro" = the whole tensor passed in).
        self._time_spec = ObjectiveSpec(time_window="macro", time_weight=config.fco_time_weight, regularizer="none")
        self._freq_spec = ObjectiveSpec(
            time_weight=0.0, regularizer="freq", freq_window="macro", freq_weight=config.fco_lambda
        )

    def _alpha_bar(self, timesteps: Tensor) -> Tensor:
        """ᾱ_t of the training scheduler for each sample, shape (B,), float32."""
        alphas_cumprod = self.diffusion.noise_scheduler.alphas_cumprod.to(device=timesteps.device, dtype=torch.float32)
        return alphas_cumprod[timesteps.long()]

    def estimate_clean_sample(self, model_output: Tensor, noisy: Tensor, timesteps: Tensor) -> Tensor:
        """x̂0 from the U-Net output at (x_t, t), as the scheduler's ``step()`` computes ``pred_original_sample``."""
        cfg = self.config
        model_output = model_output.float()
        if cfg.prediction_type == "epsilon":
            alpha_bar = self._alpha_bar(timesteps).view(-1, *([1] * (noisy.ndim - 1)))
            x0 = (noisy.float() - (1.0 - alpha_bar).sqrt() * model_output) / alpha_bar.sqrt()
        elif cfg.prediction_type == "sample":
            x0 = model_output
        else:  # DiffusionConfig validates this; kept for safety
            raise ValueError(f"Unsupported prediction type {cfg.prediction_type}")
        if cfg.fco_clip_x0 and cfg.clip_sample:
            x0 = x0.clamp(-cfg.clip_sample_range, cfg.clip_sample_range)
        return x0

    def fco_sample_weights(self, timesteps: Tensor) -> Tensor | None:
        """min(SNR_t, γ) per sample with ε-prediction and ``fco_weighting="min_snr"``; None means unweighted."""
        cfg = self.config
        if cfg.prediction_type != "epsilon" or cfg.fco_weighting == "none":
            return None
        alpha_bar = self._alpha_bar(timesteps)
        return (alpha_bar / (1.0 - alpha_bar)).clamp(max=cfg.fco_min_snr_gamma)

    def fco_loss(
        self, x0: Tensor, actions: Tensor, action_is_pad: Tensor | None = None, weights: Tensor | None = None
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """L_FCO = w_time·L_time(executed window) + λ·L_freq(horizon) of x̂0 against the expert actions.

        ``weights`` (B,) scale each sample's FCO. Both terms are quadratic in the error x̂0 − a (the DCT is
        linear), so scaling the error by √w scales each sample's L_time and L_freq by exactly w.
        """
        cfg = self.config
        actions = actions.float()
        if cfg.do_mask_loss_for_padding and action_is_pad is not None:
            x0 = torch.where(action_is_pad.unsqueeze(-1), actions, x0)
        if weights is not None:
            x0 = actions + weights.sqrt().view(-1, *([1] * (x0.ndim - 1))) * (x0 - actions)
        total = x0.new_zeros(())
        logs: dict[str, Tensor] = {}
        if cfg.fco_time_weight != 0:
            w = cfg.fco_window(cfg.fco_time_window)
            l_time, part = composite_loss(x0[:, w], actions[:, w], actions[:, w], self._time_spec)
            total, logs = total + l_time, {**logs, **part}
        if cfg.fco_lambda != 0:
            w = cfg.fco_window(cfg.fco_freq_window)
            l_freq, part = composite_loss(x0[:, w], actions[:, w], actions[:, w], self._freq_spec)
            total, logs = total + l_freq, {**logs, **part}
        return total, logs

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict[str, float] | None]:
        """LeRobot's diffusion loss (same noise, timesteps and network call), plus FCO on x̂0 when enabled."""
        if not self.config.use_fco:
            return super().forward(batch)

        captured: list[tuple[Tensor, Tensor, Tensor]] = []

        def _capture(_module, args, kwargs, output):
            x = args[0] if len(args) > 0 else kwargs["x"]
            t = args[1] if len(args) > 1 else kwargs["timestep"]
            captured.append((x, t, output))

        handle = self.diffusion.unet.register_forward_hook(_capture, with_kwargs=True)
        try:
            loss_dp, _ = super().forward(batch)
        finally:
            handle.remove()
        if len(captured) != 1:
            raise RuntimeError(f"Expected one U-Net call in the diffusion loss, saw {len(captured)}.")
        noisy, timesteps, model_output = captured[0]

        x0 = self.estimate_clean_sample(model_output, noisy, timesteps)
        weights = self.fco_sample_weights(timesteps)
        l_fco, logs = self.fco_loss(x0, batch[ACTION], batch.get("action_is_pad"), weights)
        loss = loss_dp + l_fco if self.config.fco_keep_diffusion_loss else l_fco
        out = {"loss_diffusion": loss_dp.item(), "loss_fco": l_fco.item()}
        out.update({k: v.item() for k, v in logs.items()})
        return loss, out
