"""Adroit Hammer/Door/Pen (gymnasium-robotics) with DP3 observations: 24-d hand state, point cloud, RGB."""

from __future__ import annotations

from typing import Any

from lerobot_focal.sim.rendering import ensure_offscreen_gl

# Before MuJoCo is imported (it binds its OpenGL backend then): lerobot-eval renders videos of every obs type.
ensure_offscreen_gl()

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from lerobot_focal.geometry.pointcloud import PointCloudSpec, WorkspaceBounds
from lerobot_focal.sim.raycast_camera import RENDERED_SITE_GROUPS, RayCastPointCloudSensor
from lerobot_focal.sim.rendering import make_rendering_cheap

from .episode_metrics import EpisodeMetrics
from .features import (
    AGENT_POS_KEY,
    PIXELS_KEY,
    POINTCLOUD_KEY,
    check_obs_type,
    uses_pixels,
    uses_pointcloud,
    uses_state,
)
from .focal_adroit import (
    ADROIT_DEPTH_SIZE,
    ADROIT_STATE_DIM,
    ADROIT_TASKS,
    DEFAULT_ADROIT_CAMERA,
    DEFAULT_ADROIT_WORKSPACE_HIGH,
    DEFAULT_ADROIT_WORKSPACE_LOW,
    TASK_DESCRIPTIONS,
)

# DP3's agent_pos: the 24 hand joints (wrist + fingers), without arm joints or object DoFs.
_HAND_JOINT_PREFIXES = ("WRJ", "FFJ", "MFJ", "RFJ", "LFJ", "THJ")

def _register_gymnasium_robotics() -> None:
    import gymnasium_robotics

    gym.register_envs(gymnasium_robotics)


class FocalAdroitEnv(gym.Env):
    """One Adroit task; success is gymnasium-robotics' ``info['success']`` (DP3's ``goal_achieved``)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}

    def __init__(
        self,
        task: str,
        obs_type: str = "pointcloud",
        episode_length: int = 200,
        camera_name: str = DEFAULT_ADROIT_CAMERA,
        observation_width: int = 84,
        observation_height: int = 84,
        num_points: int = 512,
        depth_width: int = ADROIT_DEPTH_SIZE,
        depth_height: int = ADROIT_DEPTH_SIZE,
        workspace_low: tuple[float, float, float] = DEFAULT_ADROIT_WORKSPACE_LOW,
        workspace_high: tuple[float, float, float] = DEFAULT_ADROIT_WORKSPACE_HIGH,
        terminate_on_success: bool = True,
        voxel_size: float = 0.0,
        raycast_threads: int | None = None,
        metrics_path: str | None = None,
        cheap_rendering: bool = True,
        draw_sites: bool = True,
    ) -> None:
        super().__init__()
        if task not in ADROIT_TASKS:
            raise ValueError(f"unknown Adroit task {task!r}; valid tasks: {', '.join(ADROIT_TASKS)}")
        check_obs_type(obs_type)
        self.metrics = EpisodeMetrics(task, metrics_path)
        self.cheap_rendering = cheap_rendering
        self.draw_sites = draw_sites
        self._viewer_ready = False
        self.last_raw_obs: np.ndarray | None = None
        self.task = task
        self.task_description = TASK_DESCRIPTIONS[task]
        self.obs_type = obs_type
        self.camera_name = camera_name
        self.terminate_on_success = terminate_on_success
        self._max_episode_steps = episode_length
        self._gym_id, action_dim = ADROIT_TASKS[task]
        self._image_size = (observation_height, observation_width)
        self._depth_size = (depth_height, depth_width)
        self.pointcloud_spec = PointCloudSpec(
            num_points=num_points, bounds=WorkspaceBounds(workspace_low, workspace_high), voxel_size=voxel_size
        )
        self.raycast_threads = raycast_threads
        self._env: gym.Env | None = None
        self._pc_sensor: RayCastPointCloudSensor | None = None
        self._hand_qpos_idx: np.ndarray | None = None

        obs_spaces: dict[str, spaces.Space] = {}
        if uses_state(obs_type):
            obs_spaces[AGENT_POS_KEY] = spaces.Box(-np.inf, np.inf, (ADROIT_STATE_DIM,), np.float32)
        if uses_pointcloud(obs_type):
            obs_spaces[POINTCLOUD_KEY] = spaces.Box(-10.0, 10.0, (num_points, 3), np.float32)
        if uses_pixels(obs_type):
            obs_spaces[PIXELS_KEY] = spaces.Box(0, 255, (*self._image_size, 3), np.uint8)
        self.observation_space = spaces.Dict(obs_spaces)
        self.action_space = spaces.Box(-1.0, 1.0, (action_dim,), np.float32)

    def _ensure_env(self) -> None:
        """Lazy, like LeRobot's envs: AsyncVectorEnv workers build their own simulator."""
        if self._env is not None:
            return
        _register_gymnasium_robotics()
        # Always rgb_array: the GL context is only made on the first render() (pixel obs, or lerobot-eval videos).
        kwargs: dict[str, Any] = {
            "render_mode": "rgb_array",
            "camera_name": self.camera_name,
            "width": self._image_size[1],
            "height": self._image_size[0],
        }
        # No gymnasium TimeLimit: the episode length is ours (lerobot-eval reads _max_episode_steps).
        env = gym.make(self._gym_id, max_episode_steps=None, disable_env_checker=True, **kwargs)
        self._env = env
        model = env.unwrapped.model
        joints = [j for j in range(model.njnt) if model.joint(j).name.startswith(_HAND_JOINT_PREFIXES)]
        self._hand_qpos_idx = model.jnt_qposadr[joints]
        assert self._hand_qpos_idx.size == ADROIT_STATE_DIM, f"expected 24 hand joints, found {joints}"
        if uses_pointcloud(self.obs_type):
            self._pc_sensor = RayCastPointCloudSensor(
                model,
                self.camera_name,
                self.pointcloud_spec,
                width=self._depth_size[1],
                height=self._depth_size[0],
                num_threads=self.raycast_threads,
                site_groups=RENDERED_SITE_GROUPS if self.draw_sites else None,
            )

    def _obs(self) -> dict[str, np.ndarray]:
        data = self._env.unwrapped.data
        obs: dict[str, np.ndarray] = {}
        if uses_state(self.obs_type):
            obs[AGENT_POS_KEY] = data.qpos[self._hand_qpos_idx].astype(np.float32)
        if uses_pointcloud(self.obs_type):
            obs[POINTCLOUD_KEY] = self._pc_sensor(data)
        if uses_pixels(self.obs_type):
            obs[PIXELS_KEY] = np.ascontiguousarray(self.render())
        return obs

    def render(self) -> np.ndarray:
        self._ensure_env()
        if not self._viewer_ready:
            if self.cheap_rendering:
                make_rendering_cheap(self._env.unwrapped.mujoco_renderer)
            self._viewer_ready = True
        return self._env.render()

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        self._ensure_env()
        super().reset(seed=seed)
        raw, _ = self._env.reset(seed=seed, options=options)
        self.last_raw_obs = np.asarray(raw)  # gymnasium-robotics' own observation (what Minari/D4RL store)
        self._steps = 0
        self.metrics.start(seed)
        return self._obs(), {"is_success": False}

    def step(self, action: np.ndarray):
        self._ensure_env()
        action = np.asarray(action)
        if action.shape != self.action_space.shape:
            raise ValueError(f"expected action of shape {self.action_space.shape}, got {action.shape}")
        self.metrics.step(action)
        raw, reward, terminated, _, info = self._env.step(action)
        self.last_raw_obs = np.asarray(raw)
        self._steps += 1
        is_success = bool(info.get("success", info.get("goal_achieved", False)))
        terminated = bool(terminated) or (self.terminate_on_success and is_success)
        truncated = self._steps >= self._max_episode_steps
        info = {**info, "task": self.task, "is_success": is_success}
        if terminated or truncated:
            atv = self.metrics.finish(is_success)["action_total_variation"]
            info["action_total_variation"] = atv
            info["final_info"] = {
                "task": self.task, "done": True, "is_success": is_success, "action_total_variation": atv
            }
        return self._obs(), float(reward), terminated, truncated, info

    def close(self) -> None:
        if self._pc_sensor is not None:
            self._pc_sensor.close()
        if self._env is not None:
            self._env.close()
