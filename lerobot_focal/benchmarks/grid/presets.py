"""Scales of the benchmark: the paper's protocol on a GPU, and a scaled-down version that fits this CPU.

The paper (SPEC §4): 10 demos per task, 3000 epochs (≈ 47 k steps at batch 128), evaluate 20 episodes at a
fixed interval, score = mean of the top-5 evaluations, mean ± std over seeds 0, 1, 2, point-cloud inputs.

The CPU preset keeps the protocol's shape and scales everything else down, and says so in every report:
fewer steps and evaluation episodes, a U-Net of 32/64/128 channels, and low-dimensional observations
(the 9-d DP3 state plus MetaWorld's 39-d observation with the object poses) for every method — LeRobot's
`diffusion` cannot read point clouds, and ray-cast point clouds would triple the evaluation time here.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace


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

    def with_overrides(self, **kwargs) -> GridPreset:
        return replace(self, **{k: v for k, v in kwargs.items() if v is not None})

    def to_dict(self) -> dict:
        return asdict(self)


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
        notes=(
            "CPU preset (scaled down from the paper): 400 steps at batch 64 instead of ~47k at 128; 10 evaluation "
            "episodes every 80 steps instead of 20 (5 evaluations, so top-5 is their mean); U-Net 32/64/128 instead of 512/1024/2048; low-dimensional "
            "observations (9-d state + MetaWorld's 39-d object-pose observation) for every method instead of "
            "point clouds; seeds 0, 1."
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
        notes=(
            "Paper preset: 10 demos, ~47k steps at batch 128 (3000 epochs of 10x200 frames), 20 evaluation "
            "episodes every 2000 steps, top-5 mean, seeds 0-2, U-Net 512/1024/2048, 512-point clouds. "
            "LeRobot's diffusion cannot read point clouds: with this preset it reads the 9-d state plus MetaWorld's "
            "39-d object-pose observation, while focal and its ablations read the point cloud and the 9-d state."
        ),
    ),
}
