"""Every method of the comparison, as the `lerobot-train` arguments that select it.

All methods share the preset's U-Net size, warm-up, batch size and step budget, and its learning rate unless
the preset gives a method its own (``method_lr``: the baselines "at their own best", each at the rate a sweep
chose for it), so a difference in the results is a difference of method. focal's ablations are its own config
switches (`--policy.ablation`, see `lerobot_focal.policy.configuration_focal.ABLATIONS`); `diffusion` is
LeRobot's policy unchanged, sampled with DDIM in 10 steps; `diffusion_fco` is the plugin's "DP w. FCO"
(LeRobot's diffusion plus the FCO loss); `diffusion_ema` is LeRobot's diffusion with an EMA copy on DP3's
schedule, acting with the EMA weights (`lerobot_focal.policy.diffusion_ema`), as DP and DP3 are evaluated;
`act` is LeRobot's ACT with its defaults except what `_act_inputs` lists (chunk length, and width on a CPU).

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

from .grid_presets import DEFAULT_TABLE_CLEARANCE, SCHEDULES, GridPreset


@dataclass(frozen=True)
class Method:
    name: str
    label: str  # as in the paper's tables
    policy_type: str
    extra: tuple[str, ...] = ()
    obs_type: str | None = None  # focal_metaworld obs_type for this method's data and env; None = the preset's
    # Its authors' learning rate, where it is not the preset's: used unless the preset's method_lr names one for
    # this method or --lr sets every method's (GridPreset.lr_for).
    own_lr: float | None = None
    # The method this one is with another setting that is not a method (its consistency target, its input): the
    # report compares it with that method as one module's contrast, not as a baseline to beat.
    variant_of: str | None = None
    # The focal the report compares this baseline with: the one on the same inputs (DP3 reads point clouds, so
    # its rival is focal on point clouds, not focal on object poses).
    rival: str = "focal"

    def train_args(self, preset: GridPreset) -> list[str]:
        lr = preset.lr_for(self.name, self.own_lr)
        if self.policy_type in _TRANSFORMERS:  # no U-Net and no scheduler (ACT trains at a constant lr)
            common = [f"--policy.type={self.policy_type}", f"--policy.optimizer_lr={lr}"]
        else:
            dims = "[" + ",".join(str(d) for d in preset.down_dims) + "]"
            common = [
                f"--policy.type={self.policy_type}",
                f"--policy.down_dims={dims}",
                f"--policy.optimizer_lr={lr}",
                f"--policy.scheduler_warmup_steps={preset.warmup_steps}",
            ]
            if preset.schedule != "cosine":  # cosine is every such policy type's default
                common.append(f"--policy.scheduler_name={SCHEDULES[preset.schedule]}")
        common += [f"--policy.device={preset.device}", "--policy.push_to_hub=false"]
        return common + _INPUTS[self.policy_type](preset, self.obs_type_for(preset)) + list(self.extra)

    def obs_type_for(self, preset: GridPreset) -> str:
        return self.obs_type or preset.obs_type


def _encoder_widths(preset: GridPreset) -> list[str]:
    """focal's encoder widths where the preset sets them; dp3 takes the same flags, so both get one encoder."""
    dim = preset.focal_encoder_dim
    return [] if dim is None else [f"--policy.pointcloud_feature_dim={dim}", f"--policy.state_feature_dim={dim}"]


def is_camera(obs_type: str) -> bool:
    """Whether a method of this focal_metaworld obs type observes the camera (pixels, pixels_agent_pos)."""
    return obs_type.startswith("pixels")


def _image_args(preset: GridPreset) -> list[str]:
    """The camera: a random crop in training, as LeRobot's image policies do, and a ResNet-18 trained from scratch
    with GroupNorm (Diffusion Policy's image encoder; nothing is downloaded)."""
    crop = preset.image_crop
    return [f"--policy.crop_shape=[{crop},{crop}]", "--policy.pretrained_backbone_weights=null",
            "--policy.use_group_norm=true"]


def _focal_inputs(preset: GridPreset, obs_type: str) -> list[str]:
    if is_camera(obs_type):  # one RGB camera + the 9-d state
        return [*_encoder_widths(preset), "--policy.use_env_state=false", "--policy.use_images=true",
                *_image_args(preset)]
    # With a point cloud focal reads it and the 9-d state (DP3's inputs); without one, the object poses.
    use_env_state = preset.env_state and obs_type != "pointcloud"
    switches = [f"--policy.use_env_state={str(use_env_state).lower()}", "--policy.use_images=false"]
    return _encoder_widths(preset) + switches


def _require_env_state(preset: GridPreset, policy: str) -> None:
    if not preset.env_state:
        raise ValueError(
            f"preset {preset.name!r} gives no observation.environment_state, and LeRobot's {policy} needs it (or "
            "images): set env_state in the preset"
        )


#: DP/DP3's chunking: 2 observations, 16-step horizon, 8 executed; DDIM with 10 steps at inference.
DP3_CHUNKING = (
    "--policy.n_obs_steps=2",
    "--policy.horizon=16",
    "--policy.n_action_steps=8",
    "--policy.noise_scheduler_type=DDIM",
    "--policy.num_inference_steps=10",
)


def _diffusion_inputs(preset: GridPreset, obs_type: str) -> list[str]:
    if is_camera(obs_type):
        return _image_args(preset) + list(DP3_CHUNKING)
    _require_env_state(preset, "diffusion")
    return list(DP3_CHUNKING)


def _dp3_inputs(preset: GridPreset, obs_type: str) -> list[str]:
    # DP3 reads the cloud and the 9-d state (never the object poses), through focal's encoder at focal's widths.
    return _encoder_widths(preset) + list(DP3_CHUNKING)


#: ACT's chunk in a 200-step MetaWorld episode (see `_act_inputs`).
ACT_CHUNK = 50


def _act_inputs(preset: GridPreset, obs_type: str) -> list[str]:
    """LeRobot's ACT with its defaults (one observation step, VAE with KL weight 10, 4 + 1 transformer layers,
    4-layer VAE encoder, dropout 0.1, AdamW 1e-5 with weight decay 1e-4 at a constant lr, no temporal
    ensembling, mean-std normalisation), on the same state + object-pose inputs, except:

    * chunk_size = n_action_steps = 50 instead of 100. A MetaWorld episode is 200 steps: with 100 the policy
      re-plans once per episode, after half of it blind; ACT's 100 is a quarter of its 400-step simulated
      ALOHA episodes (transfer-cube), and 50 keeps that share, so it re-plans 4 times per episode as there.
    * dim_model / dim_feedforward from the preset's ``act_width`` (CPU presets: 128 / 800 instead of 512 /
      3200, the same 6.25 ratio; 2.5 M parameters, near focal's 1.8 M at U-Net 32/64/128). ACT's default size
      (40 M parameters without an image backbone) takes 4.7 s per batch-64 step at chunk 50 on one of these
      CPU cores, 10 h for the 8000 steps of a CPU preset; the CPU presets shrink every network (the U-Net is
      32/64/128 instead of 512/1024/2048) and this is ACT's share of that. ``None`` keeps ACT's default size.
    """
    if is_camera(obs_type):
        # ACT's authors start from ImageNet weights, which cannot be downloaded here: its ResNet-18 trains from
        # scratch (with its own BatchNorm, frozen only for pretrained weights), the one change images force.
        args = ["--policy.pretrained_backbone_weights=null"]
    else:
        _require_env_state(preset, "ACT")
        args = []
    args += [f"--policy.chunk_size={ACT_CHUNK}", f"--policy.n_action_steps={ACT_CHUNK}"]
    if preset.act_width is not None:
        dim_model, dim_feedforward = preset.act_width
        args += [f"--policy.dim_model={dim_model}", f"--policy.dim_feedforward={dim_feedforward}"]
    return args


def act_config(preset: GridPreset, input_features: dict, output_features: dict, **fields):
    """The ``ACTConfig`` that `_act_inputs`' flags give LeRobot's ACT in ``preset``, for the benchmarks that build
    the grid's ACT in-process (`act-precision`, `speed`); ``fields`` adds other settings (device, lr)."""
    from lerobot.policies.act.configuration_act import ACTConfig

    width = {} if preset.act_width is None else {"dim_model": preset.act_width[0],
                                                  "dim_feedforward": preset.act_width[1]}
    return ACTConfig(input_features=input_features, output_features=output_features, chunk_size=ACT_CHUNK,
                     n_action_steps=ACT_CHUNK, **width, **fields)


_INPUTS: dict[str, Callable[[GridPreset, str], list[str]]] = {
    "focal": _focal_inputs,
    "diffusion": _diffusion_inputs,
    "diffusion_fco": _diffusion_inputs,
    "diffusion_ema": _diffusion_inputs,
    "dp3": _dp3_inputs,
    "act": _act_inputs,
}
#: Policy types without a U-Net or a learning-rate schedule: no --policy.down_dims / scheduler flags.
_TRANSFORMERS = ("act",)


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
        Method("focal_online", "FocalPolicy (online target)", "focal", (ONLINE,), variant_of="focal"),
        Method("focal_pc", "FocalPolicy (512-pt cloud)", "focal", obs_type="pointcloud", variant_of="focal"),
        Method("wo_las_ema", "w/o LAS (EMA target)", "focal", ("--policy.ablation=wo_las",)),
        Method("wo_fco_las_ema", "w/o FCO & LAS (EMA target)", "focal", ("--policy.ablation=wo_fco_las",)),
        # Not in the paper: w/o LAS with L_time over all L steps, as FlowPolicy's consistency loss covers them. It
        # tests whether that window is why w/o LAS trails w/o FCO & LAS at the plateau budget (docs/benchmarks.md).
        Method("wo_las_macro", "w/o LAS, L_time on all L steps", "focal",
               ("--policy.ablation=wo_las", "--policy.loss.time_window=macro", ONLINE)),
        # Not in the paper: FlowPolicy's objective with one segment instead of two; with wo_las_macro it tells which
        # of the two differences left between w/o LAS and w/o FCO & LAS (segments, λ·L_freq) makes the gap.
        Method("wo_fco_las_1seg", "w/o FCO & LAS, one segment", "focal",
               ("--policy.ablation=wo_fco_las", "--policy.loss.cfm_num_segments=1", ONLINE)),
        Method("diffusion", "DP (DDIM 10)", "diffusion"),
        Method("diffusion_fco", "DP w. FCO (DDIM 10)", "diffusion_fco"),
        # DP as its authors (and DP3's) evaluate it: an EMA copy on DP3's schedule, acting with the EMA weights.
        Method("diffusion_ema", "DP with EMA (DDIM 10)", "diffusion_ema"),
        # DP3: diffusion_ema on the point cloud and the 9-d state, through focal's encoder (lerobot_focal.policy.dp3).
        Method("dp3", "DP3 (512-pt cloud, DDIM 10)", "dp3", obs_type="pointcloud", rival="focal_pc"),
        Method("act", "ACT", "act", own_lr=1e-5),  # ACT's default lr (its authors'), with no schedule
        # One RGB camera (MetaWorld's corner2) + the 9-d state, no object poses: what a camera-only user has.
        Method("focal_rgb", "FocalPolicy (RGB)", "focal", obs_type="pixels_agent_pos", variant_of="focal"),
        Method("diffusion_rgb", "DP with EMA (RGB, DDIM 10)", "diffusion_ema", obs_type="pixels_agent_pos",
               rival="focal_rgb"),
        Method("act_rgb", "ACT (RGB)", "act", own_lr=1e-5, obs_type="pixels_agent_pos", rival="focal_rgb"),
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
#: The grid with every baseline at its own best (issue 31), in phases: the first answers the main question
#: (focal against diffusion with EMA and ACT, each at its own learning rate), the second adds the FlowPolicy
#: objective, which the plateau grid already measured with the other estimator.
FAIR_PHASES: tuple[tuple[str, ...], ...] = (
    ("focal", "diffusion_ema", "act"),
    ("wo_fco_las",),
)
#: From a camera (preset cpu_rgb): focal against diffusion with its EMA and ACT, each on one RGB camera + state.
RGB_PHASES: tuple[tuple[str, ...], ...] = (("focal_rgb", "diffusion_rgb", "act_rgb"),)
_PHASE_SETS = {"plateau": PLATEAU_PHASES, "fair": FAIR_PHASES, "rgb": RGB_PHASES}


def resolve_method_phases(spec: str) -> list[list[Method]]:
    """Methods in run phases: ``a,b|c`` runs every (task, seed) of a and b before any of c. ``plateau`` expands
    to :data:`PLATEAU_PHASES`, ``fair`` to :data:`FAIR_PHASES`, ``core`` and ``all`` to one phase each. A method
    appears once, in its first phase."""
    choices = f"core, all, plateau, fair, rgb, {', '.join(METHODS)}"
    phases: list[list[str]] = []
    seen: set[str] = set()
    for phase_spec in spec.split("|"):
        phase: list[str] = []
        for item in (s.strip() for s in phase_spec.split(",")):
            if not item:
                continue
            if item in _PHASE_SETS:
                for extra in _PHASE_SETS[item]:
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


def _flag(args: list[str], name: str) -> str | None:
    values = [a.split("=", 1)[1] for a in args if a.startswith(f"--policy.{name}=")]
    return values[-1] if values else None


def given(name: str, preset: dict) -> dict[str, str]:
    """What `name` is given in a grid whose preset is `preset` (as grid.json stores it): learning rate and schedule,
    which weights act and which target it trains against, chunk (predicted / executed steps), observations. Read
    off the very `lerobot-train` arguments the grid passes, with each policy type's defaults where it passes none."""
    from dataclasses import fields

    p = GridPreset.from_dict(preset)
    method = METHODS[name]
    args = method.train_args(p)
    lr = float(_flag(args, "optimizer_lr"))
    if method.policy_type in _TRANSFORMERS:
        schedule = "constant"
        chunk = f"{_flag(args, 'chunk_size')} / {_flag(args, 'n_action_steps')}"
        acts = "online weights"
    elif method.policy_type == "focal":
        from lerobot_focal.policy.configuration_focal import FocalConfig

        default = {f.name: f.default for f in fields(FocalConfig)}
        h = int(_flag(args, "chunk_size") or default["chunk_size"])
        n = int(_flag(args, "n_chunks") or default["n_chunks"])
        schedule = f"{p.schedule}, {p.warmup_steps} warm-up"
        chunk = f"{h * n} / {h}"
        target = "online" if ONLINE in args else "EMA"
        acts = f"EMA weights; consistency target {target}"
    else:
        schedule = f"{p.schedule}, {p.warmup_steps} warm-up"
        chunk = f"{_flag(args, 'horizon')} / {_flag(args, 'n_action_steps')}"
        acts = "EMA weights" if method.policy_type in ("diffusion_ema", "dp3") else "online weights (no EMA)"
    obs = method.obs_type_for(p)
    if is_camera(obs):
        inputs = f"RGB {p.image_size}² (crop {p.image_crop}²) + 9-d state"
    else:
        points = (f"{p.train_points}-pt" if p.train_points == p.eval_points
                  else f"{p.train_points}-pt (evaluated on {p.eval_points})")
        table = ("" if p.table_clearance == DEFAULT_TABLE_CLEARANCE else " (table kept)" if p.table_clearance is None
                 else f" (table cropped {p.table_clearance * 1000:g} mm above)")
        inputs = f"{points} cloud{table} + 9-d state" if obs == "pointcloud" else "9-d state"
        if p.env_state and (obs != "pointcloud" or method.policy_type not in ("focal", "dp3")):
            inputs += " + 39-d object poses"
    return {"lr": f"{lr:g}", "schedule": schedule, "acts": acts, "chunk": chunk, "inputs": inputs,
            "steps": str(p.for_method(name).steps)}
