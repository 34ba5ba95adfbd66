"""Every method of the comparison, as the `lerobot-train` arguments that select it.

All methods share the preset's U-Net size, optimiser settings, batch size and step budget, so a difference in
the results is a difference of method. focal's ablations are its own config switches (`--policy.ablation`, see
`lerobot_focal.policy.configuration_focal.ABLATIONS`); `diffusion` is LeRobot's policy unchanged, sampled with
DDIM in 10 steps; `diffusion_fco` is the plugin's "DP w. FCO" (LeRobot's diffusion plus the FCO loss).

Consistency target θ⁻: each method gets the one its own authors use. focal follows the paper (EMA); the
FlowPolicy-style ablations (adjacent anchors r = τ + Δ) use the online weights under stop-gradient, as
FlowPolicy's and FocalPolicy's public code do. With Δ = 0.01 the data signal enters only at τ ≥ 0.99 and must
hop ~100 times to reach the noise end; behind an EMA whose time constant is hundreds of steps each hop waits,
so an EMA target starves those ablations at CPU budgets (`*_ema` variants keep that comparison available).
``focal_online`` reports focal with the online target beside the paper's EMA.
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
    obs_type: str | None = None  # focal_metaworld obs_type for this method's data and env; None = the preset's

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
        return common + _INPUTS[self.policy_type](preset, self.obs_type_for(preset)) + list(self.extra)

    def obs_type_for(self, preset: GridPreset) -> str:
        return self.obs_type or preset.obs_type


def _focal_inputs(preset: GridPreset, obs_type: str) -> list[str]:
    args = []
    if preset.focal_encoder_dim is not None:
        dim = preset.focal_encoder_dim
        args += [f"--policy.pointcloud_feature_dim={dim}", f"--policy.state_feature_dim={dim}"]
    # With a point cloud focal reads it and the 9-d state (DP3's inputs); without one, the object poses.
    use_env_state = preset.env_state and obs_type != "pointcloud"
    return args + [f"--policy.use_env_state={str(use_env_state).lower()}", "--policy.use_images=false"]


def _diffusion_inputs(preset: GridPreset, obs_type: str) -> list[str]:
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


_INPUTS: dict[str, Callable[[GridPreset, str], list[str]]] = {
    "focal": _focal_inputs,
    "diffusion": _diffusion_inputs,
    "diffusion_fco": _diffusion_inputs,
}


ONLINE = "--policy.consistency_target=online"


def _ablation(name: str, label: str, *extra: str) -> Method:
    return Method(name, label, "focal", (f"--policy.ablation={name}", *extra))


METHODS: dict[str, Method] = {
    m.name: m
    for m in [
        Method("focal", "FocalPolicy", "focal"),
        _ablation("wo_las", "w/o LAS", ONLINE),
        _ablation("wo_fco_las", "w/o FCO & LAS", ONLINE),
        _ablation("time_only_fco", "L_time only"),
        _ablation("freq_only_fco", "L_freq only"),
        _ablation("fixed_r", "fixed r = 1"),
        _ablation("fco_full_macro", "FCO-Full-Macro"),
        _ablation("fco_prox_freq", "FCO-Prox-Freq"),
        _ablation("anchor_0.4_0.5", "anchor (0.4, 0.5)"),
        _ablation("anchor_1.4_0.5", "anchor (1.4, 0.5)"),
        Method("focal_online", "FocalPolicy (online target)", "focal", (ONLINE,)),
        Method("focal_pc", "FocalPolicy (512-pt cloud)", "focal", obs_type="pointcloud"),
        Method("wo_las_ema", "w/o LAS (EMA target)", "focal", ("--policy.ablation=wo_las",)),
        Method("wo_fco_las_ema", "w/o FCO & LAS (EMA target)", "focal", ("--policy.ablation=wo_fco_las",)),
        # Not in the paper: w/o LAS with L_time over all L steps, as FlowPolicy's consistency loss covers them. It
        # tests whether that window is why w/o LAS trails w/o FCO & LAS at the plateau budget (docs/benchmarks.md).
        Method("wo_las_macro", "w/o LAS, L_time on all L steps", "focal",
               ("--policy.ablation=wo_las", "--policy.time_loss_window=macro", ONLINE)),
        # Not in the paper: FlowPolicy's objective with one segment instead of two; with wo_las_macro it tells which
        # of the two differences left between w/o LAS and w/o FCO & LAS (segments, λ·L_freq) makes the gap.
        Method("wo_fco_las_1seg", "w/o FCO & LAS, one segment", "focal",
               ("--policy.ablation=wo_fco_las", "--policy.cfm_num_segments=1", ONLINE)),
        Method("diffusion", "DP (DDIM 10)", "diffusion"),
        Method("diffusion_fco", "DP w. FCO (DDIM 10)", "diffusion_fco"),
    ]
}

#: Methods that answer a question about this implementation, not one of the paper's: never in `--methods all`.
DIAGNOSTIC_METHODS: tuple[str, ...] = ("wo_las_macro", "wo_fco_las_1seg")
#: What `--methods all` expands to: the full comparison of the paper's tables.
PAPER_METHODS: tuple[str, ...] = tuple(m for m in METHODS if m not in DIAGNOSTIC_METHODS)
#: The minimum comparison, what the smoke-scale CPU grid in docs/benchmarks/grid_cpu covers.
CORE_METHODS: tuple[str, ...] = ("focal", "wo_las", "wo_fco_las", "diffusion")
#: The plateau grid, in phases: the first answers the main question (focal against the strongest baseline and
#: the FlowPolicy objective), the second the rest of the comparison, the third focal on point clouds.
PLATEAU_PHASES: tuple[tuple[str, ...], ...] = (
    ("focal", "diffusion", "wo_fco_las"),
    ("focal_online", "wo_las", "diffusion_fco"),
    ("focal_pc",),
)


def resolve_method_phases(spec: str) -> list[list[Method]]:
    """Methods in run phases: ``a,b|c`` runs every (task, seed) of a and b before any of c. ``plateau`` expands
    to :data:`PLATEAU_PHASES`, ``core`` and ``all`` to one phase each. A method appears once, in its first phase."""
    choices = f"core, all, plateau, {', '.join(METHODS)}"
    phases: list[list[str]] = []
    seen: set[str] = set()
    for phase_spec in spec.split("|"):
        phase: list[str] = []
        for item in (s.strip() for s in phase_spec.split(",")):
            if not item:
                continue
            if item == "plateau":
                for extra in PLATEAU_PHASES:
                    phases.append([m for m in extra if m not in seen])
                    seen.update(extra)
                continue
            names = PAPER_METHODS if item == "all" else CORE_METHODS if item == "core" else (item,)
            for name in names:
                if name not in METHODS:
                    raise ValueError(f"unknown method {name!r}; choose from: {choices}")
                if name not in seen:
                    phase.append(name)
                    seen.add(name)
        phases.append(phase)
    phases = [p for p in phases if p]
    if not phases:
        raise ValueError(f"no method given; choose from: {choices}")
    return [[METHODS[n] for n in p] for p in phases]


def resolve_methods(spec: str) -> list[Method]:
    return [m for phase in resolve_method_phases(spec) for m in phase]
