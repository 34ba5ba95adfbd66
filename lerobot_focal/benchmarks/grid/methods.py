"""Every method of the comparison, as the `lerobot-train` arguments that select it.

All methods share the preset's U-Net size, optimiser settings, batch size and step budget, so a difference in
the results is a difference of method. focal's ablations are its own config switches (`--policy.ablation`, see
`lerobot_focal.policy.configuration_focal.ABLATIONS`); `diffusion` is LeRobot's policy unchanged, sampled with
DDIM in 10 steps; `diffusion_fco` is the plugin's "DP w. FCO" (LeRobot's diffusion plus the FCO loss).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from .presets import GridPreset


@dataclass(frozen=True)
class Method:
    name: str
    label: str  # as in the paper's tables
    policy_type: str
    extra: tuple[str, ...] = ()

    def train_args(self, preset: GridPreset) -> list[str]:
        dims = "[" + ",".join(str(d) for d in preset.down_dims) + "]"
        common = [
            f"--policy.type={self.policy_type}",
            f"--policy.down_dims={dims}",
            f"--policy.optimizer_lr={preset.lr}",
            f"--policy.scheduler_warmup_steps={preset.warmup_steps}",
            f"--policy.device={preset.device}",
            "--policy.push_to_hub=false",
        ]
        return common + _INPUTS[self.policy_type](preset) + list(self.extra)


def _focal_inputs(preset: GridPreset) -> list[str]:
    args = []
    if preset.focal_encoder_dim is not None:
        dim = preset.focal_encoder_dim
        args += [f"--policy.pointcloud_feature_dim={dim}", f"--policy.state_feature_dim={dim}"]
    # With a point cloud focal reads it and the 9-d state (DP3's inputs); without one, the object poses.
    use_env_state = preset.env_state and preset.obs_type != "pointcloud"
    return args + [f"--policy.use_env_state={str(use_env_state).lower()}"]


def _diffusion_inputs(preset: GridPreset) -> list[str]:
    if not preset.env_state:
        raise ValueError(
            f"preset {preset.name!r} gives no observation.environment_state, and LeRobot's diffusion needs it (or "
            "images): set env_state in the preset"
        )
    # DP/DP3's chunking: 2 observations, 16-step horizon, 8 executed; DDIM with 10 steps at inference.
    return [
        "--policy.n_obs_steps=2",
        "--policy.horizon=16",
        "--policy.n_action_steps=8",
        "--policy.noise_scheduler_type=DDIM",
        "--policy.num_inference_steps=10",
    ]


_INPUTS: dict[str, Callable[[GridPreset], list[str]]] = {
    "focal": _focal_inputs,
    "diffusion": _diffusion_inputs,
    "diffusion_fco": _diffusion_inputs,
}


def _ablation(name: str, label: str) -> Method:
    return Method(name, label, "focal", (f"--policy.ablation={name}",))


METHODS: dict[str, Method] = {
    m.name: m
    for m in [
        Method("focal", "FocalPolicy", "focal"),
        _ablation("wo_las", "w/o LAS"),
        _ablation("wo_fco_las", "w/o FCO & LAS"),
        _ablation("time_only_fco", "L_time only"),
        _ablation("freq_only_fco", "L_freq only"),
        _ablation("fixed_r", "fixed r = 1"),
        _ablation("fco_full_macro", "FCO-Full-Macro"),
        _ablation("fco_prox_freq", "FCO-Prox-Freq"),
        _ablation("anchor_0.4_0.5", "anchor (0.4, 0.5)"),
        _ablation("anchor_1.4_0.5", "anchor (1.4, 0.5)"),
        Method("focal_online", "focal, online target", "focal", ("--policy.consistency_target=online",)),
        Method("diffusion", "DP (DDIM 10)", "diffusion"),
        Method("diffusion_fco", "DP w. FCO (DDIM 10)", "diffusion_fco"),
    ]
}

#: What `--methods all` expands to: the full comparison of the paper's tables.
PAPER_METHODS: tuple[str, ...] = tuple(METHODS)
#: The issue's minimum comparison, what the CPU run in docs/benchmarks/ covers.
CORE_METHODS: tuple[str, ...] = ("focal", "wo_las", "wo_fco_las", "diffusion")


def resolve_methods(spec: str) -> list[Method]:
    names: list[str] = []
    for item in (s.strip() for s in spec.split(",")):
        if not item:
            continue
        if item == "all":
            names += PAPER_METHODS
        elif item == "core":
            names += CORE_METHODS
        elif item in METHODS:
            names.append(item)
        else:
            raise ValueError(f"unknown method {item!r}; choose from: core, all, {', '.join(METHODS)}")
    if not names:
        raise ValueError(f"no method given; choose from: core, all, {', '.join(METHODS)}")
    return [METHODS[n] for n in dict.fromkeys(names)]
