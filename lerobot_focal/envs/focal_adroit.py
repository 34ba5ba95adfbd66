"""``--env.type=focal_adroit``: Adroit Hammer, Door and Pen with DP3 point clouds and 24-d hand state."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import gymnasium as gym

from lerobot.configs import PolicyFeature
from lerobot.envs.configs import EnvConfig, _make_vec_env_cls
from lerobot.processor import PolicyProcessorPipeline

from .common import check_obs_type, env_features, env_features_map, resolve_names, uses_pointcloud
from .processor import PointCloudObservationStep

if TYPE_CHECKING:  # the env module imports gymnasium_robotics and mujoco: only load it when an env is built
    from .adroit_env import FocalAdroitEnv

#: Short task name -> (gymnasium id, action dim). Action dims as in DP3.
ADROIT_TASKS: dict[str, tuple[str, int]] = {
    "hammer": ("AdroitHandHammer-v1", 26),
    "door": ("AdroitHandDoor-v1", 28),
    "pen": ("AdroitHandPen-v1", 24),
}
ADROIT_STATE_DIM = 24
ADROIT_DEPTH_SIZE = 192
#: DP3 renders hammer/door from a 'top' camera that gymnasium-robotics' models do not have; 'vil_camera'
#: exists in all three and is the one DP3 uses for pen.
DEFAULT_ADROIT_CAMERA = "vil_camera"
#: World-frame box over the hand and objects. Its floor sits 5 mm above the table top (z = 0): with the table
#: inside, 54-91 % of the 512 points landed on the bare table; without it they cover hand, tool and object.
DEFAULT_ADROIT_WORKSPACE_LOW: tuple[float, float, float] = (-0.5, -0.5, 0.005)
DEFAULT_ADROIT_WORKSPACE_HIGH: tuple[float, float, float] = (0.5, 0.5, 0.8)
TASK_DESCRIPTIONS: dict[str, str] = {
    "hammer": "Pick up the hammer and drive the nail into the board.",
    "door": "Undo the latch and swing the door open.",
    "pen": "Reorient the pen to match the target orientation.",
}


ADROIT_GROUPS: dict[str, list[str]] = {"all": list(ADROIT_TASKS)}


def _canonical_task(name: str) -> str:
    """Accept 'hammer', 'adroit-hammer' and gymnasium's 'AdroitHandHammer-v1'."""
    name = name.strip()
    for short, (gym_id, _) in ADROIT_TASKS.items():
        if name == gym_id:
            return short
    return name.lower().removeprefix("adroit-").removeprefix("adroit_")


@EnvConfig.register_subclass("focal_adroit")
@dataclass
class FocalAdroitEnvConfig(EnvConfig):
    """``task``: hammer, door, pen, 'all', or a comma-separated list. One task per config for training."""

    task: str = "hammer"
    # Adroit's control rate: frame_skip 5 x timestep 2 ms.
    fps: int = 100
    episode_length: int = 200
    obs_type: str = "pointcloud"
    camera_name: str = DEFAULT_ADROIT_CAMERA
    observation_width: int = 84
    observation_height: int = 84
    num_points: int = 512
    # 'vil_camera' sees the hand from afar: at 84x84 the hammer scene leaves only ~270 pixels in the workspace
    # (fewer than 512 distinct points); 192x192 gives >= 512 for all three tasks at 12-28 ms CPU per cloud.
    depth_width: int = ADROIT_DEPTH_SIZE
    depth_height: int = ADROIT_DEPTH_SIZE
    workspace_low: tuple[float, float, float] = DEFAULT_ADROIT_WORKSPACE_LOW
    workspace_high: tuple[float, float, float] = DEFAULT_ADROIT_WORKSPACE_HIGH
    terminate_on_success: bool = True
    # Voxel grid (m) applied before FPS for speed; 0 = exact DP3 recipe (FPS over all cropped points).
    # Exact DP3 FPS: the cropped clouds are small here, and a 1 cm grid would merge the pen and fingers.
    voxel_size: float = 0.0
    raycast_threads: int | None = None
    # Append one JSON line per finished episode (task, seed, success, length, action_total_variation) here.
    metrics_path: str | None = None
    # Shadows and reflections off in RGB frames: ~8x faster with software OpenGL (pixels obs and eval videos).
    cheap_rendering: bool = True
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=env_features_map)

    def __post_init__(self) -> None:
        check_obs_type(self.obs_type)
        requested = ",".join(_canonical_task(t) for t in self.task.split(",") if t.strip())
        self.tasks = resolve_names(requested, ADROIT_TASKS, ADROIT_GROUPS, "Adroit task")
        action_dims = {ADROIT_TASKS[t][1] for t in self.tasks}
        if len(action_dims) != 1:
            raise ValueError(f"tasks {self.tasks} have different action sizes {sorted(action_dims)}; evaluate them separately")
        self.features = env_features(
            self.obs_type,
            action_dim=action_dims.pop(),
            state_dim=ADROIT_STATE_DIM,
            num_points=self.num_points,
            image_hw=(self.observation_height, self.observation_width),
        )

    @property
    def gym_kwargs(self) -> dict[str, Any]:
        return {
            "obs_type": self.obs_type,
            "episode_length": self.episode_length,
            "camera_name": self.camera_name,
            "observation_width": self.observation_width,
            "observation_height": self.observation_height,
            "num_points": self.num_points,
            "depth_width": self.depth_width,
            "depth_height": self.depth_height,
            "workspace_low": tuple(self.workspace_low),
            "workspace_high": tuple(self.workspace_high),
            "terminate_on_success": self.terminate_on_success,
            "voxel_size": self.voxel_size,
            "raycast_threads": self.raycast_threads,
            "metrics_path": self.metrics_path,
            "cheap_rendering": self.cheap_rendering,
        }

    def make_single_env(self, task: str | None = None) -> FocalAdroitEnv:
        from .adroit_env import FocalAdroitEnv

        name = _canonical_task(task) if task else self.tasks[0]
        return FocalAdroitEnv(task=name, **self.gym_kwargs)

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        if not isinstance(n_envs, int) or n_envs <= 0:
            raise ValueError(f"n_envs must be a positive int; got {n_envs}")
        from lerobot.envs.utils import freeze_after_episode_end

        from .adroit_env import FocalAdroitEnv

        env_cls = _make_vec_env_cls(use_async_envs, n_envs)
        kwargs = self.gym_kwargs
        extra = {"context": "forkserver"} if env_cls is gym.vector.AsyncVectorEnv else {}
        out: dict[str, dict[int, gym.vector.VectorEnv]] = {}
        for name in self.tasks:
            fns = [freeze_after_episode_end(lambda tn=name: FocalAdroitEnv(task=tn, **kwargs)) for _ in range(n_envs)]
            out[name] = {0: env_cls(fns, **extra)}
        return out

    def get_env_processors(self):
        steps = [PointCloudObservationStep(num_points=self.num_points)] if uses_pointcloud(self.obs_type) else []
        return PolicyProcessorPipeline(steps=steps), PolicyProcessorPipeline(steps=[])
