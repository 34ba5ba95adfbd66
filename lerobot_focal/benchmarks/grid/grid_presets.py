"""Scales of the benchmark: the paper's protocol on a GPU, and scaled-down versions that fit a CPU.

The paper: 10 demos per task, 3000 epochs (≈ 47 k steps at batch 128), evaluate 20 episodes at a
fixed interval, score = mean of the top-5 evaluations, mean ± std over seeds 0, 1, 2, point-cloud inputs.

The CPU presets keep the protocol's shape and scale everything else down, and say so in every report: a U-Net
of 32/64/128 channels, and low-dimensional observations (the 9-d DP3 state plus MetaWorld's 39-d observation
with the object poses) for every method — LeRobot's `diffusion` cannot read point clouds, and ray-cast point
clouds multiply the evaluation time on a CPU (methods such as ``focal_pc`` ask for them explicitly).
``cpu`` is a quick smoke-scale grid (400 steps, every method still climbing); ``cpu_plateau`` trains to the
budget where focal's success stops rising and is the one whose numbers compare with the paper's.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, fields, replace

from lerobot_focal.envs.focal_metaworld import DEFAULT_TABLE_CLEARANCE

#: Reset seeds of the training demos start here. LeRobot's periodic evaluation inside `lerobot-train` resets its
#: envs with seeds ``--seed`` … ``--seed + n_episodes − 1`` (0 … 21 for the grid's seeds 0-2 and 20 episodes), and
#: a MetaWorld reset seed fixes the object and goal positions: demos collected from seeds 0, 1, … would put the
#: training configurations into every evaluation. The demos start far above them.
DEMO_SEED = 1_000
#: Demo seeds must stay in [DEMO_SEED, DEMO_SEED_END): below the held-out, final-evaluation and expert-gap seeds.
DEMO_SEED_END = 100_000


@dataclass(frozen=True)
class GridPreset:
    name: str
    steps: int
    batch_size: int
    eval_every: int  # K: evaluate every K training steps (LeRobot's --env_eval_freq)
    eval_episodes: int  # N per evaluation
    top_k: int  # score = mean of the top-k evaluations
    demos: int  # expert episodes per task for training
    heldout_demos: int  # expert episodes per task for the open-loop metrics (different seeds)
    down_dims: tuple[int, ...]
    lr: float
    warmup_steps: int
    obs_type: str  # focal_metaworld obs_type for env + datasets
    env_state: bool  # add MetaWorld's 39-d observation as observation.environment_state
    episode_length: int = 200
    seeds: tuple[int, ...] = (0, 1, 2)
    device: str = "cpu"
    num_threads: int | None = 1  # torch threads per run (OMP_NUM_THREADS); None = library default
    notes: str = ""
    # focal's point-cloud / state encoder widths; None = FocalConfig's defaults (the paper's)
    focal_encoder_dim: int | None = None
    extra_train_args: tuple[str, ...] = field(default_factory=tuple)
    # After training, `lerobot-eval` of the final checkpoint on this many fresh episodes (seeds never used by the
    # periodic evaluations, the demos or the held-out set); 0 = none. Top-k of the periodic evaluations is
    # optimistic (it picks the best checkpoints on the very episodes it reports), this number is not.
    final_episodes: int = 0
    # Methods that run on fewer seeds than the grid: (method, n) runs it on the first n of the grid's seeds. For a
    # method whose runs cost several times the others' (point clouds on a CPU), so that a complete grid stays
    # affordable; `--seeds` still chooses which seeds those first n are.
    seed_caps: tuple[tuple[str, int], ...] = ()
    # First reset seed of the training demos (a MetaWorld reset seed fixes the object and goal placement). Every
    # training seed of a grid learns from the same demos; another value draws another set of placements.
    demo_seed: int = DEMO_SEED
    # How the periodic evaluations inside `lerobot-train` place the objects. "fixed": LeRobot's reset seeds as
    # given, the same N placements at every evaluation (top-k then picks checkpoints on one set of episodes).
    # "fresh": as DP3's runner, which the paper's numbers come from, new placements at every evaluation, other
    # for every training seed (seeds.py): top-k then picks the luckiest of independent draws of N episodes.
    periodic_eval: str = "fixed"
    # Every training seed learns from its own demos (seeds demo_seed + 1000·k …, their own data folder), so the
    # spread over seeds includes the draw of the demos; False: every seed learns from the same demos.
    demos_per_seed: bool = False
    # Learning rates of single methods, (method, lr) pairs: each baseline at the rate a sweep chose for it (or its
    # authors' default, see methods.py); every other method trains at ``lr``. ``--lr`` sets every method's.
    method_lr: tuple[tuple[str, float], ...] = ()
    # Step budgets of single methods, (method, steps) pairs: a method whose curve plateaus at another budget than
    # the preset's (measured, as the plateau probe measures it) trains to its own, with the same number of
    # evaluations (every steps / (self.steps / eval_every) steps); every other method trains ``steps``.
    method_steps: tuple[tuple[str, int], ...] = ()
    # ACT's transformer width (dim_model, dim_feedforward); None = ACT's defaults (512, 3200).
    act_width: tuple[int, int] | None = None
    # Learning-rate schedule after the warm-up, for the methods that have one (focal's family and the diffusion
    # family; ACT trains at a constant rate whatever this says). "cosine": to zero at ``steps`` (LeRobot's and the
    # paper's). "constant": the rate stays, so a learning curve that flattens does so because the method has
    # learned what it can, not because the rate reached zero (how the plateau budget is measured).
    schedule: str = "cosine"
    # Camera methods (obs type pixels_agent_pos: one RGB camera + the 9-d state, no object poses): frames of
    # image_size² pixels from MetaWorld's corner2 camera, randomly cropped to image_crop² in training (centre crop
    # at inference), as LeRobot's image policies crop.
    image_size: int = 84
    image_crop: int = 76
    # Points per cloud in the demos a point-cloud method trains on, and in the evaluation env. DP3 trains on 1024
    # and evaluates on 512 (its max-pool encoder takes any count, as focal's and dp3's here do); 512 and 512 is
    # what the grids ran before these fields existed.
    train_points: int = 512
    eval_points: int = 512
    # Point clouds: the table top is cropped this far above its surface (m, the env's default); None keeps the
    # table in the clouds (DP3's crop keeps a band of it, and on sweep-into the raised top with its goal hole).
    table_clearance: float | None = DEFAULT_TABLE_CLEARANCE

    # Fields whose value differs from the named preset's (set by with_overrides): they name the folders below.
    overridden: tuple[str, ...] = ()

    def with_overrides(self, **kwargs) -> GridPreset:
        changed = {k: v for k, v in kwargs.items() if v is not None and v != getattr(self, k)}
        # A given lr is an override even at the preset's value: it replaces every method's own rate (method_lr).
        marked = set(changed) | ({"lr"} if kwargs.get("lr") is not None else set())
        return replace(self, **changed, overridden=tuple(sorted(set(self.overridden) | marked)))

    def with_none(self, name: str) -> GridPreset:
        """`name` set to None, as an override where the preset's value is not None (`with_overrides` reads None
        as "not given")."""
        if getattr(self, name) is None:
            return self
        return replace(self, **{name: None}, overridden=tuple(sorted({*self.overridden, name})))

    def lr_for(self, method: str, own_lr: float | None = None) -> float:
        """The learning rate `method` trains at: ``--lr`` if given (every method), else the preset's rate for
        that method (``method_lr``), else the method's own default (`own_lr`, e.g. ACT's authors'), else ``lr``."""
        if "lr" in self.overridden:
            return self.lr
        return dict(self.method_lr).get(method, self.lr if own_lr is None else own_lr)

    def for_method(self, method: str) -> GridPreset:
        """The preset a run of `method` trains with: its own step budget (``method_steps``) if it has one, with the
        same number of evaluations; else this preset. A ``--steps`` other than the preset's sets every method's
        budget (as ``--lr`` sets every method's rate), so a shortened grid shortens every method."""
        steps = None if "steps" in self.overridden else dict(self.method_steps).get(method)
        if steps is None or steps == self.steps:
            return self
        evaluations = self.steps // self.eval_every
        if steps % evaluations:
            raise ValueError(f"method_steps gives {method} {steps} steps, not a multiple of the preset's "
                             f"{evaluations} evaluations: choose a multiple of {evaluations}")
        return replace(self, steps=steps, eval_every=steps // evaluations)

    def _folder(self, fields: tuple[str, ...] | None = None) -> str:
        parts = [f"{k}={_folder_value(getattr(self, k))}" for k in self.overridden if fields is None or k in fields]
        return self.name + ("+" + ",".join(parts) if parts else "")

    @property
    def runs_folder(self) -> str:
        """Where this preset's runs live under the work dir: an overridden preset never reuses (or, on a restart,
        deletes) the named preset's run folders."""
        return self._folder()

    @property
    def data_folder(self) -> str:
        """Where its datasets live: shared by every preset that collects the same demos."""
        return self._folder(DATA_FIELDS)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> GridPreset:
        """The preset a ``to_dict`` (or ``grid.json``'s ``"preset"``) holds, overrides included. A field the
        dictionary lacks takes today's default: grids recorded before the field existed ran with that
        behaviour (each new field's default is the earlier behaviour). A key that is no field is refused."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"not fields of a grid preset: {', '.join(unknown)} (fields: {', '.join(sorted(names))})")

        def as_tuple(value):  # JSON stores tuples as lists
            return tuple(as_tuple(v) for v in value) if isinstance(value, list) else value

        return cls(**{k: as_tuple(v) for k, v in data.items()})


def capped_seeds(seed_caps: Iterable[Sequence], method: str, seeds: Sequence[int]) -> list[int]:
    """The seeds a grid runs `method` on, given a preset's ``seed_caps`` (as a GridPreset holds them or as
    ``grid.json`` stores them: pairs of method and count)."""
    cap = {name: int(n) for name, n in seed_caps}.get(method)
    return list(seeds) if cap is None else list(seeds)[:cap]


#: The fields the collected datasets depend on (besides the observation types, which name their own folders).
DATA_FIELDS = ("demos", "heldout_demos", "episode_length", "obs_type", "env_state", "demo_seed", "demos_per_seed",
               "image_size", "train_points", "table_clearance")
PERIODIC_EVALS = ("fixed", "fresh")
#: ``schedule`` values and the diffusers schedule each selects (``--policy.scheduler_name``).
SCHEDULES = {"cosine": "cosine", "constant": "constant_with_warmup"}


def _folder_value(v: object) -> str:
    return "-".join(map(str, v)) if isinstance(v, tuple | list) else str(v)


PRESETS: dict[str, GridPreset] = {
    "cpu": GridPreset(
        name="cpu",
        steps=400,
        batch_size=64,
        eval_every=80,
        eval_episodes=10,
        top_k=5,
        demos=10,
        heldout_demos=3,
        down_dims=(32, 64, 128),
        lr=1e-3,
        warmup_steps=50,
        obs_type="state",
        env_state=True,
        seeds=(0, 1),
        device="cpu",
        num_threads=1,
        focal_encoder_dim=64,  # as configs/focal_cpu.json
        act_width=(128, 800),  # ACT shrunk like the U-Net (methods._act_inputs)
        notes=(
            "CPU preset (scaled down from the paper): 400 steps at batch 64 instead of ~47k at 128; 10 evaluation "
            "episodes every 80 steps instead of 20 (5 evaluations, so top-5 is their mean); U-Net 32/64/128 "
            "instead of 512/1024/2048; low-dimensional "
            "observations (9-d state + MetaWorld's 39-d object-pose observation) for every method instead of "
            "point clouds; seeds 0, 1."
        ),
    ),
    "cpu_plateau": (_CPU_PLATEAU := GridPreset(
        name="cpu_plateau",
        steps=8_000,
        batch_size=64,
        eval_every=500,
        eval_episodes=20,
        top_k=5,
        demos=10,
        heldout_demos=3,
        down_dims=(32, 64, 128),
        lr=1e-3,
        warmup_steps=100,
        obs_type="state",
        env_state=True,
        seeds=(0, 1, 2),
        device="cpu",
        num_threads=1,
        focal_encoder_dim=64,
        act_width=(128, 800),
        final_episodes=50,
        # focal on 512-point clouds: a run costs 5-10x a low-dimensional one on a CPU (ray casting, the encoder).
        seed_caps=(("focal_pc", 2),),
        notes=(
            "CPU preset at the plateau budget: 10 full-length expert demos per task (DP3's collection: 200 steps, "
            "kept when successful on ≥ 5 steps), 8000 steps at batch 64 (256 epochs of the 2000 frames), "
            "20 evaluation episodes every 500 steps (16 evaluations; score = mean of the top-5, the paper's "
            "protocol) and the final checkpoint on 50 fresh episodes; U-Net 32/64/128 instead of 512/1024/2048; "
            "low-dimensional observations (9-d state + MetaWorld's 39-d object poses, min-max normalised) for "
            "every method unless the method says otherwise; seeds 0, 1, 2 (focal on point clouds: 0, 1)."
        ),
    )),
    # cpu_plateau with the paper's estimator, the draw of the demos in the spread over seeds, and every baseline at
    # its own best. Its methods: `--methods fair` (methods.FAIR_PHASES), focal, diffusion_ema and act first (the
    # main question), then wo_fco_las. Learning rates: focal and wo_fco_las at `lr`; diffusion_ema and act at the
    # rates of the sweep in docs/benchmarks/lr_sweep_fair (method_lr): diffusion_ema 1e-3 (of 1e-4, 3e-4, 1e-3 on
    # disassemble, seed 0: 4, 24 and 44 % on 50 fresh episodes); act 1e-4 (of its authors' 1e-5 and 1e-4: 4 and
    # 70 %). Both winners sit at the top of their sweep (a higher rate is untried). The budget, 20000 steps with 16
    # evaluations (every 1250), comes from the plateau probe (docs/benchmarks/plateau_probe_fair: each method at a
    # constant rate for 24000 steps on disassemble and push-wall): focal's 3-evaluation mean is within 10 points of
    # its best by step 6000-10000, diffusion_ema's by 13000-15000; with the cosine schedule over 20000 steps the
    # rate at step 15000 is still 15 % of its peak, so the slowest method plateaus before the schedule anneals.
    # ACT trains 10000 steps (method_steps, 16 evaluations every 625), a budget the CPU sets, not its curve: at
    # ACT's width 128/800 a batch-64 step costs 0.89 s on one thread of a 2-core CPU (`act-precision`, float32),
    # so 20000 steps are ~5 h per run and ACT's 15 runs ~75 h; 10000 steps take ~2.5 h on one thread, less alone
    # on both cores (`OMP_NUM_THREADS=2 lerobot-focal-bench grid ... --methods act --jobs 1`). ACT trains at a
    # constant rate, so its 10000 steps are the first half of a 20000-step curve, not a shorter schedule. A
    # partial 20000-step run (its checkpoints lost) had flattened on disassemble from step 6250 (75-85 % per
    # evaluation) and still rose on push-wall at 12500 (50 -> 70 %).
    "cpu_fair": (_CPU_FAIR := replace(
        _CPU_PLATEAU,
        name="cpu_fair",
        steps=20_000,
        eval_every=1_250,
        periodic_eval="fresh",
        demos_per_seed=True,
        method_lr=(("diffusion_ema", 1e-3), ("act", 1e-4)),  # the lr sweep's choices
        method_steps=(("act", 10_000),),  # what a 2-core CPU affords (above)
        notes=(
            "CPU preset with the paper's estimator: as cpu_plateau (10 full-length demos, batch 64, 16 evaluations "
            "of 20 episodes, top-5, the final checkpoint on 50 fresh episodes, U-Net 32/64/128, low-dimensional "
            "observations) but trained to the plateau of focal's and diffusion's curves, 20000 steps (evaluations "
            "every 1250; the plateau probe, docs/benchmarks.md), and every periodic evaluation draws new placements, "
            "other for every training seed, as DP3's runner does (top-5 picks the luckiest of 16 independent draws "
            "of 20 episodes), and every training seed learns from its own 10 demos (the ± over seeds includes the "
            "draw of the demos). Baselines at their own best: diffusion with its EMA (diffusion_ema) at the rate a "
            "sweep chose (1e-3 of 1e-4/3e-4/1e-3), LeRobot's ACT with its defaults (chunk 50, width 128/800) but at "
            "the rate the same sweep chose (1e-4 of its authors' 1e-5 and 1e-4; at 1e-5 it scored 4 % fresh on "
            "disassemble after 8000 steps). Both chosen rates are the highest swept. ACT trains 10000 steps (16 "
            "evaluations every 625) at its constant rate: at 0.89 s per step on one CPU thread, 20000 steps would "
            "cost ~5 h a run; its curve on push-wall may still rise after 10000."
        ),
    )),
    # From a camera: one RGB camera + the 9-d state, no object poses, for focal, diffusion with its EMA and ACT
    # (`--methods rgb`, methods.RGB_PHASES), on cpu_fair's protocol. The image baselines train at the rates the
    # low-dimensional lr sweep chose for the same policies (diffusion 1e-3, ACT 1e-4); two seeds, as a camera run
    # costs ~15-25 low-dim ones on a CPU (lerobot-focal-bench camera-step).
    "cpu_rgb": replace(
        _CPU_FAIR,
        name="cpu_rgb",
        steps=8_000,  # focal's plateau (the probe): a camera step costs ~15-25 low-dim ones on a CPU
        eval_every=500,
        seeds=(0, 1),
        method_lr=(("diffusion_rgb", 1e-3), ("act_rgb", 1e-4)),
        notes=(
            "CPU preset for camera inputs: cpu_fair's protocol (fresh placements at every evaluation, per-seed "
            "demos, 8000 steps at batch 64, top-5 of 16 evaluations of 20 episodes, the final checkpoint on 50 "
            "fresh episodes) with one 84x84 RGB camera (MetaWorld's corner2, random crop 76x76 in training) + the "
            "9-d state and no object poses; image encoders are ResNet-18s trained from scratch (nothing is "
            "downloaded); diffusion with EMA at 1e-3 and ACT at 1e-4 (the low-dim lr sweep's choices); seeds 0, 1."
        ),
    ),
    "paper": GridPreset(
        name="paper",
        steps=47_000,
        batch_size=128,
        eval_every=2_000,
        eval_episodes=20,
        top_k=5,
        demos=10,
        heldout_demos=5,
        down_dims=(512, 1024, 2048),
        lr=1e-4,
        warmup_steps=500,
        obs_type="pointcloud",
        env_state=True,  # for diffusion; focal reads the point cloud and the 9-d state
        seeds=(0, 1, 2),
        device="cuda",
        num_threads=None,
        final_episodes=100,
        periodic_eval="fresh",  # DP3's runner: new placements at every evaluation
        notes=(
            "Paper preset: 10 demos, ~47k steps at batch 128 (3000 epochs of 10x200 frames), 20 evaluation "
            "episodes every 2000 steps, top-5 mean, seeds 0-2, U-Net 512/1024/2048, 512-point clouds. "
            "LeRobot's diffusion cannot read point clouds: with this preset it reads the 9-d state plus MetaWorld's "
            "39-d object-pose observation, while focal and its ablations read the point cloud and the 9-d state."
        ),
    ),
}
