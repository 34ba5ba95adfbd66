"""Configuration of ``diffusion_fco``: LeRobot's ``diffusion`` policy trained with the Foresight Composite Objective.

Registered as LeRobot policy type ``diffusion_fco`` (``--policy.type=diffusion_fco``). It subclasses LeRobot's
``DiffusionConfig`` unchanged (every ``--policy.*`` flag of ``diffusion`` works the same) and only adds the FCO
fields below. See ``modeling_diffusion_fco`` for the loss.
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

from lerobot_focal.config_errors import reports_config_errors, require_non_negative, require_positive

FCO_WINDOWS = ("executed", "horizon")
FCO_WEIGHTINGS = ("min_snr", "none")


@PreTrainedConfig.register_subclass("diffusion_fco")
@reports_config_errors("--policy.type=diffusion_fco")
@dataclass
class DiffusionFcoConfig(DiffusionConfig):
    """``DiffusionConfig`` plus the Foresight Composite Objective (paper §4.1, Table 2 "w. FCO").

    Args (in addition to ``DiffusionConfig``'s):
        use_fco: add the FCO term to the loss. ``False`` gives exactly LeRobot's ``diffusion`` loss.
        fco_lambda: λ, the weight of L_freq inside FCO (paper: 1e-4).
        fco_time_weight: weight of L_time inside FCO (paper: 1).
        fco_time_window: the steps L_time supervises: ``"executed"`` (paper: the ``n_action_steps`` actions
            ``select_action`` executes, i.e. steps ``[n_obs_steps-1, n_obs_steps-1+n_action_steps)`` of the
            horizon) or ``"horizon"`` (all ``horizon`` steps).
        fco_freq_window: the steps L_freq supervises: ``"horizon"`` (paper: the whole predicted trajectory) or
            ``"executed"``.
        fco_keep_diffusion_loss: keep LeRobot's standard diffusion loss and add FCO on top (default). ``False``
            trains on FCO alone; with ``prediction_type="sample"`` (as DP3) that is the paper's literal
            "time-domain loss on the execution chunk, frequency-domain loss on the predicted trajectory".
        fco_clip_x0: clamp x̂0 to ±``clip_sample_range`` (when ``clip_sample`` is on) before FCO, exactly as the
            DDPM/DDIM ``step()`` clamps its ``pred_original_sample`` at inference.
        fco_weighting: per-sample weight of the FCO term at diffusion step t, with ε-prediction only.
            ``"min_snr"`` (default): min(SNR_t, γ), SNR_t = ᾱ_t / (1 − ᾱ_t), the Min-SNR-γ weighting of an x̂0
            loss (Hang et al., 2023). An x̂0 error is the ε error over √SNR_t, so unweighted, the FCO gradient
            outgrows the ε-loss's by 1/SNR_t (4·10⁶ at the last step of the default 100-step schedule); with
            min(SNR_t, γ) it stays within the ε-loss's scale at every t. ``"none"``: unweighted, as this
            policy trained before the option existed. With ``prediction_type="sample"`` x̂0 is the network
            output and the diffusion loss itself is an unweighted x̂0 loss, so FCO stays unweighted there.
        fco_min_snr_gamma: γ of ``"min_snr"`` (Hang et al.'s default: 5).
    """

    use_fco: bool = True
    fco_lambda: float = 1e-4
    fco_time_weight: float = 1.0
    fco_time_window: str = "executed"
    fco_freq_window: str = "horizon"
    fco_keep_diffusion_loss: bool = True
    fco_clip_x0: bool = True
    fco_weighting: str = "min_snr"
    fco_min_snr_gamma: float = 5.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("fco_time_window", "fco_freq_window"):
            value = getattr(self, name)
            if value not in FCO_WINDOWS:
                raise ValueError(f"`{name}` must be one of {list(FCO_WINDOWS)}. Got {value!r}.")
        if self.fco_weighting not in FCO_WEIGHTINGS:
            raise ValueError(f"`fco_weighting` must be one of {list(FCO_WEIGHTINGS)}. Got {self.fco_weighting!r}.")
        # A negative weight makes the optimiser maximise that error.
        require_non_negative(fco_lambda=self.fco_lambda, fco_time_weight=self.fco_time_weight)
        require_positive(fco_min_snr_gamma=self.fco_min_snr_gamma)
        if self.use_fco and not self.fco_keep_diffusion_loss and self.fco_lambda == 0 and self.fco_time_weight == 0:
            raise ValueError(
                "fco_keep_diffusion_loss=false trains on FCO alone, and both of its weights (fco_lambda, "
                "fco_time_weight) are 0: nothing would train. Give one a weight > 0 or keep the diffusion loss."
            )
        if self.n_action_steps < 1 or self.n_obs_steps - 1 + self.n_action_steps > self.horizon:
            raise ValueError(
                "The executed window [n_obs_steps-1, n_obs_steps-1+n_action_steps) must lie inside the horizon. "
                f"Got {self.n_obs_steps=}, {self.n_action_steps=}, {self.horizon=}."
            )

    def fco_window(self, which: str) -> slice:
        """The slice of the ``horizon`` axis that ``which`` (``"executed"`` | ``"horizon"``) denotes."""
        if which == "executed":
            start = self.n_obs_steps - 1
            return slice(start, start + self.n_action_steps)
        return slice(0, self.horizon)
