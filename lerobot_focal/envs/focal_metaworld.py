"""``--env.type=focal_metaworld``: every MetaWorld v3 task with DP3 point clouds and 9-d state."""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass, field
from importlib import resources
from typing import TYPE_CHECKING, Any

import gymnasium as gym

from lerobot.configs import PolicyFeature
from lerobot.envs.configs import EnvConfig, _make_vec_env_cls
from lerobot.processor import PolicyProcessorPipeline

from .common import (
    DEFAULT_VOXEL_SIZE,
    check_obs_type,
    env_features,
    env_features_map,
    resolve_names,
    uses_pixels,
    uses_pointcloud,
)
from .processor import PointCloudObservationStep

if TYPE_CHECKING:  # the env module imports metaworld and mujoco: only load it when an env is built
    from .metaworld_env import FocalMetaworldEnv

METAWORLD_STATE_DIM = 9
METAWORLD_ACTION_DIM = 4
#: MetaWorld v3's own observation: hand, gripper, two object poses, the previous frame of those, goal.
METAWORLD_ENV_STATE_DIM = 39
#: DP3 moves camera ``corner2`` here; LeRobot's own metaworld env uses another position.
DP3_CORNER2_POS: tuple[float, float, float] = (0.6, 0.295, 0.8)
#: World-frame box around the table top, objects and arm; drops floor, back walls and background.
DEFAULT_WORKSPACE_LOW: tuple[float, float, float] = (-0.6, 0.2, -0.02)
DEFAULT_WORKSPACE_HIGH: tuple[float, float, float] = (0.6, 1.05, 0.75)


def _load_lerobot_metaworld_config() -> dict[str, Any]:
    """LeRobot's task table, read as data: ``lerobot.envs.metaworld`` itself imports metaworld."""
    return json.loads((resources.files("lerobot.envs") / "metaworld_config.json").read_text())


_MW_CONFIG = _load_lerobot_metaworld_config()
#: Task -> language description, as LeRobot ships it.
TASK_DESCRIPTIONS: dict[str, str] = dict(_MW_CONFIG["TASK_DESCRIPTIONS"])
#: The 50 MetaWorld v3 task names LeRobot ships (lerobot/envs/metaworld_config.json).
METAWORLD_TASKS: tuple[str, ...] = tuple(sorted(TASK_DESCRIPTIONS))
#: The difficulty split of Seo et al. used by DP3/FlowPolicy/FocalPolicy, as LeRobot ships it.
METAWORLD_GROUPS: dict[str, list[str]] = {k: list(v) for k, v in _MW_CONFIG["DIFFICULTY_TO_TASKS"].items()}


def _canonical_task(name: str) -> str:
    """Accept 'pick-place', 'pick-place-v3' and LeRobot's 'metaworld-pick-place-v3' spellings."""
    name = name.strip().removeprefix("metaworld-")
    if name in METAWORLD_GROUPS or name.endswith("-v3"):
        return name
    return f"{name}-v3" if f"{name}-v3" in TASK_DESCRIPTIONS else name


def resolve_metaworld_tasks(task: str) -> dict[str, list[str]]:
    """'easy,pick-place' -> {'easy': [...28 tasks], 'pick-place-v3': ['pick-place-v3']} (eval groups)."""
    out: dict[str, list[str]] = {}
    for item in (t for t in task.split(",") if t.strip()):
        canonical = _canonical_task(item)
        out[canonical] = resolve_names(canonical, METAWORLD_TASKS, METAWORLD_GROUPS, "MetaWorld task")
    if not out:
        resolve_names("", METAWORLD_TASKS, METAWORLD_GROUPS, "MetaWorld task")  # raises with the valid list
    return out


@EnvConfig.register_subclass("focal_metaworld")
@dataclass
class FocalMetaworldEnvConfig(EnvConfig):
    """``task``: a v3 task, a difficulty group (easy, medium, hard, very_hard) or a comma-separated mix."""

    task: str = "pick-place-v3"
    # MetaWorld's control rate: frame_skip 5 x timestep 2.5 ms.
    fps: int = 80
    # DP3/FocalPolicy episodes are 200 env steps.
    episode_length: int = 200
    obs_type: str = "pointcloud"
    # Also emit MetaWorld's 39-d observation (object poses) as observation.environment_state. It is what
    # LeRobot's `diffusion` needs without images, so the CPU benchmark gives every method the same input.
    env_state: bool = False
    render_mode: str = "rgb_array"
    camera_name: str = "corner2"
    camera_pos: tuple[float, float, float] | None = DP3_CORNER2_POS
    observation_width: int = 128
    observation_height: int = 128
    num_points: int = 512
    depth_width: int = 128
    depth_height: int = 128
    workspace_low: tuple[float, float, float] = DEFAULT_WORKSPACE_LOW
    workspace_high: tuple[float, float, float] = DEFAULT_WORKSPACE_HIGH
    # Voxel grid (m) applied before FPS for speed; 0 = exact DP3 recipe (FPS over all cropped points).
    voxel_size: float = DEFAULT_VOXEL_SIZE
    # Threads per env for ray casting (None = 1, the fastest here with 2 busy cores).
    raycast_threads: int | None = None
    # Append one JSON line per finished episode (task, seed, success, length, action_total_variation) here.
    metrics_path: str | None = None
    # Shadows and reflections off in RGB frames: ~8x faster with software OpenGL (pixels obs and eval videos).
    cheap_rendering: bool = True
    # False: render() (videos only, never observations) returns a blank 16x16 frame. `lerobot-train` renders
    # every env of 4 evaluation episodes to video at each evaluation (hard-coded); with software OpenGL that was
    # ~70 % of a benchmark run's time here. The benchmark grid turns it off; simulation and metrics are unchanged.
    render_videos: bool = True
    multitask_eval: bool = True
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=env_features_map)

    def __post_init__(self) -> None:
        check_obs_type(self.obs_type)
        if not self.render_videos and uses_pixels(self.obs_type):
            raise ValueError(
                f"render_videos=false blanks rendered frames, but obs_type={self.obs_type!r} observes pixels: "
                "keep render_videos=true or use obs_type state/pointcloud"
            )
        self.tasks_by_group = resolve_metaworld_tasks(self.task)
        self.features = env_features(
            self.obs_type,
            action_dim=METAWORLD_ACTION_DIM,
            state_dim=METAWORLD_STATE_DIM,
            num_points=self.num_points,
            image_hw=(self.observation_height, self.observation_width),
            env_state_dim=METAWORLD_ENV_STATE_DIM if self.env_state else None,
        )

    @property
    def gym_kwargs(self) -> dict[str, Any]:
        return {
            "obs_type": self.obs_type,
            "env_state": self.env_state,
            "camera_name": self.camera_name,
            "camera_pos": self.camera_pos,
            "episode_length": self.episode_length,
            "observation_width": self.observation_width,
            "observation_height": self.observation_height,
            "num_points": self.num_points,
            "depth_width": self.depth_width,
            "depth_height": self.depth_height,
            "workspace_low": tuple(self.workspace_low),
            "workspace_high": tuple(self.workspace_high),
            "voxel_size": self.voxel_size,
            "raycast_threads": self.raycast_threads,
            "metrics_path": self.metrics_path,
            "cheap_rendering": self.cheap_rendering,
            "render_videos": self.render_videos,
        }

    def make_single_env(self, task: str | None = None) -> FocalMetaworldEnv:
        """One un-vectorised env (for data collection and tests); default: the first configured task."""
        from .metaworld_env import FocalMetaworldEnv

        if task is None:
            task = next(iter(self.tasks_by_group.values()))[0]
        (name,) = resolve_names(_canonical_task(task), METAWORLD_TASKS, {}, "MetaWorld task")
        return FocalMetaworldEnv(task=name, **self.gym_kwargs)

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        """Same {group: {task_id: VectorEnv}} layout as LeRobot's ``create_metaworld_envs``."""
        if not isinstance(n_envs, int) or n_envs <= 0:
            raise ValueError(f"n_envs must be a positive int; got {n_envs}")
        from lerobot.envs.utils import _LazyAsyncVectorEnv, freeze_after_episode_end

        from .metaworld_env import FocalMetaworldEnv

        env_cls = _make_vec_env_cls(use_async_envs, n_envs)
        kwargs = self.gym_kwargs
        out: dict[str, dict[int, Any]] = defaultdict(dict)
        cached: tuple | None = None
        for group, tasks in self.tasks_by_group.items():
            for tid, name in enumerate(tasks):
                fns = [(lambda tn=name: FocalMetaworldEnv(task=tn, **kwargs)) for _ in range(n_envs)]
                if env_cls is gym.vector.AsyncVectorEnv:
                    # LeRobot's lazy async env (one task's workers alive at a time) adds the freeze wrapper.
                    lazy = _LazyAsyncVectorEnv(fns, *(cached or (None, None, None)))
                    cached = cached or (lazy.observation_space, lazy.action_space, lazy.metadata)
                    out[group][tid] = lazy
                else:
                    # Stop simulating a finished sub-env (and its autoreset) until lerobot-eval's next rollout.
                    out[group][tid] = env_cls([freeze_after_episode_end(fn) for fn in fns])
        return {group: dict(task_map) for group, task_map in out.items()}

    def get_env_processors(self):
        steps = [PointCloudObservationStep(num_points=self.num_points)] if uses_pointcloud(self.obs_type) else []
        return PolicyProcessorPipeline(steps=steps), PolicyProcessorPipeline(steps=[])
