"""Configuration of ``diffusion_ema``: LeRobot's ``diffusion`` policy evaluated with EMA weights, as DP and DP3 are.

Registered as LeRobot policy type ``diffusion_ema`` (``--policy.type=diffusion_ema``). It subclasses LeRobot's
``DiffusionConfig`` (every ``--policy.*`` flag of ``diffusion`` works the same) and adds the EMA fields below;
two of ``DiffusionConfig``'s defaults change to DP3's inference: DDIM with 10 steps.

LeRobot 0.6.1's ``diffusion`` keeps no EMA copy, while Diffusion Policy and DP3 (the paper's baseline) train
one and evaluate it: comparing against the online weights would put the baseline below its authors' setting.
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

from lerobot_focal.config_errors import reports_config_errors
from lerobot_focal.policy.ema import check_ema_settings


@PreTrainedConfig.register_subclass("diffusion_ema")
@reports_config_errors("--policy.type=diffusion_ema")
@dataclass
class DiffusionEmaConfig(DiffusionConfig):
    """``DiffusionConfig`` plus an EMA copy of the network (DP3's ``EMAModel`` schedule, as focal's).

    Args (in addition to ``DiffusionConfig``'s):
        use_ema: keep the EMA copy (a frozen submodule saved with every checkpoint). ``False`` gives exactly
            LeRobot's ``diffusion``.
        ema_power: decay = 1 − (1 + step)^−power (DP3: 0.75).
        ema_min_decay / ema_max_decay: clip of the decay (DP3: 0 and 0.9999).
        ema_update_after_step: the EMA copies the weights until this step.
        use_ema_for_inference: act with the EMA weights (DP3) or the online ones.
        noise_scheduler_type / num_inference_steps: defaults changed to DDIM with 10 steps (DP3's inference);
            LeRobot's ``diffusion`` defaults to DDPM with 100.
    """

    noise_scheduler_type: str = "DDIM"
    num_inference_steps: int | None = 10

    use_ema: bool = True
    ema_power: float = 0.75
    ema_min_decay: float = 0.0
    ema_max_decay: float = 0.9999
    ema_update_after_step: int = 0
    use_ema_for_inference: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        check_ema_settings(self)
        if self.use_ema_for_inference and not self.use_ema:
            raise ValueError("use_ema_for_inference=true needs use_ema=true (or set use_ema_for_inference=false).")
