"""`FocalSimEnvConfig`: what the MetaWorld and Adroit env configs share.

Both suites deliver the same observation kinds (9-d / 24-d state, a ray-cast 512-point cloud, pixels), build
one env class per task with the same keyword arguments, vectorise the same way and map the cloud to
`observation.pointcloud` with the same env processor step. A suite declares its defaults (camera, image and
depth sizes, workspace box), its tasks and its env class; the rest lives here once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import gymnasium as gym
from lerobot.configs import PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.processor import PolicyProcessorPipeline

from lerobot_focal.config_errors import require_non_negative, require_positive

from .features import env_features_map, uses_pointcloud
from .processor import PointCloudObservationStep
from .vector import make_vector_env


@dataclass
class FocalSimEnvConfig(EnvConfig):
    episode_length: int = 200
    obs_type: str = "pointcloud"
    camera_name: str = ""
    observation_width: int = 128
    observation_height: int = 128
    num_points: int = 512
    depth_width: int = 128
    depth_height: int = 128
    workspace_low: tuple[float, float, float] = (-1.0, -1.0, -1.0)
    workspace_high: tuple[float, float, float] = (1.0, 1.0, 1.0)
    # Voxel grid (m) applied before farthest-point sampling, for speed; 0 = DP3's exact recipe.
    voxel_size: float = 0.0
    # Threads per env for ray casting (None = 1, the fastest when the other cores are busy).
    raycast_threads: int | None = None
    # Append one JSON line per finished episode (task, seed, success, length, action_total_variation) here.
    metrics_path: str | None = None
    # Shadows and reflections off in RGB frames: ~8x faster with software OpenGL (pixels obs and eval videos).
    cheap_rendering: bool = True
    # Clouds contain the sites an OpenGL render draws (MetaWorld's goal marker, the arm's small site spheres),
    # as DP3's clouds, made from rasterised depth, do. False: matter only, as a real depth camera sees it.
    draw_sites: bool = True
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=env_features_map)

    #: Fields passed to every env of the suite as keyword arguments.
    GYM_FIELDS: ClassVar[tuple[str, ...]] = (
        "obs_type", "episode_length", "camera_name", "observation_width", "observation_height", "num_points",
        "depth_width", "depth_height", "workspace_low", "workspace_high", "voxel_size", "raycast_threads",
        "metrics_path", "cheap_rendering", "draw_sites",
    )
    #: A suite's own extra keyword arguments.
    EXTRA_GYM_FIELDS: ClassVar[tuple[str, ...]] = ()

    # --- what a suite provides --------------------------------------------------------------------------
    def task_groups(self) -> dict[str, list[str]]:
        """{evaluation group: [task, ...]} in LeRobot's env layout."""
        raise NotImplementedError

    def env_class(self) -> type[gym.Env]:
        """The suite's env class (imported only when an env is built: it imports the simulator)."""
        raise NotImplementedError

    def canonical_task(self, task: str) -> str:
        return task

    # --- shared ----------------------------------------------------------------------------------------
    def check_fields(self) -> None:
        """The fields every suite shares; each suite's `__post_init__` calls this first."""
        require_positive(
            episode_length=self.episode_length, fps=self.fps, observation_width=self.observation_width,
            observation_height=self.observation_height, num_points=self.num_points, depth_width=self.depth_width,
            depth_height=self.depth_height, raycast_threads=self.raycast_threads,
        )
        require_non_negative(voxel_size=self.voxel_size)
        lo, hi = tuple(self.workspace_low), tuple(self.workspace_high)
        if len(lo) != 3 or len(hi) != 3 or any(a >= b for a, b in zip(lo, hi, strict=True)):
            raise ValueError(
                f"workspace_low {lo} must be below workspace_high {hi} on x, y and z (the world-frame box the point "
                "cloud is cropped to, metres)."
            )

    @property
    def gym_kwargs(self) -> dict[str, Any]:
        kwargs = {name: getattr(self, name) for name in (*self.GYM_FIELDS, *self.EXTRA_GYM_FIELDS)}
        kwargs["workspace_low"] = tuple(self.workspace_low)
        kwargs["workspace_high"] = tuple(self.workspace_high)
        return kwargs

    def make_single_env(self, task: str | None = None) -> gym.Env:
        """One un-vectorised env (data collection, tests); default: the first configured task."""
        name = self.canonical_task(task) if task else next(iter(self.task_groups().values()))[0]
        return self.env_class()(task=name, **self.gym_kwargs)

    def _env_factory(self, task: str) -> Callable[[], gym.Env]:
        cls, kwargs = self.env_class(), self.gym_kwargs
        return lambda: cls(task=task, **kwargs)

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, Any]]:
        """{group: {task_id: vector env}}, the layout of LeRobot's own multi-task envs."""
        if not isinstance(n_envs, int) or n_envs <= 0:
            raise ValueError(f"n_envs must be a positive int; got {n_envs}")
        spaces: list = []
        return {
            group: {tid: make_vector_env([self._env_factory(name) for _ in range(n_envs)], use_async_envs, spaces)
                    for tid, name in enumerate(tasks)}
            for group, tasks in self.task_groups().items()
        }

    def get_env_processors(self):
        steps = [PointCloudObservationStep(num_points=self.num_points)] if uses_pointcloud(self.obs_type) else []
        return PolicyProcessorPipeline(steps=steps), PolicyProcessorPipeline(steps=[])
