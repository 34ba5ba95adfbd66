"""MetaWorld v3 gym env with DP3 observations: 9-d state, 512-point cloud, optional RGB.

Built on LeRobot's ``MetaworldEnv`` so that seeding, task descriptions, the scripted expert
(``expert_policy``), success reporting (``info["is_success"]``, terminate on first success, ``final_info``)
and ``lerobot-eval``'s expectations stay exactly LeRobot's; only env construction and observation
formatting differ. Those two are LeRobot's private hooks ``_ensure_env`` and ``_format_raw_obs`` (and
MetaWorld's ``_freeze_rand_vec``): overriding them is what keeps the rest LeRobot's instead of a copy.
`tests/envs/test_registration.py` fails loudly if LeRobot stops calling them from ``reset``.
"""

from __future__ import annotations

import functools
from dataclasses import replace
from typing import Any

from lerobot_focal.sim.rendering import ensure_offscreen_gl

# Before MuJoCo is imported (it binds its OpenGL backend then): lerobot-eval renders videos of every obs type.
ensure_offscreen_gl()

import metaworld
import mujoco
import numpy as np
from gymnasium import spaces
from lerobot.envs.metaworld import MetaworldEnv

from lerobot_focal.geometry.pointcloud import PointCloudSpec, WorkspaceBounds
from lerobot_focal.sim.raycast_camera import RENDERED_SITE_GROUPS, RayCastPointCloudSensor
from lerobot_focal.sim.rendering import make_rendering_cheap

from .episode_metrics import EpisodeMetrics
from .features import (
    AGENT_POS_KEY,
    DEFAULT_VOXEL_SIZE,
    ENV_STATE_KEY,
    PIXELS_KEY,
    POINTCLOUD_KEY,
    check_obs_type,
    uses_pixels,
    uses_pointcloud,
    uses_state,
)
from .focal_metaworld import (
    DEFAULT_TABLE_CLEARANCE,
    DEFAULT_WORKSPACE_HIGH,
    DEFAULT_WORKSPACE_LOW,
    DP3_CORNER2_POS,
    METAWORLD_ENV_STATE_DIM,
    METAWORLD_STATE_DIM,
)


@functools.cache
def metaworld_task(env_name: str) -> tuple[type, Any]:
    """The env class and the task (``MT1(env_name, seed=42)``'s first, as LeRobot uses) of a MetaWorld task.

    Cached per process: ``MT1`` builds an env and samples all 50 of its tasks to hand out one, and LeRobot's
    `lerobot-train` builds its evaluation envs anew at every evaluation, so without the cache that work ran once
    per env and evaluation. The task is plain data that ``set_task`` only reads, so envs can share it.
    """
    mt1 = metaworld.MT1(env_name, seed=42)
    return mt1.train_classes[env_name], mt1.train_tasks[0]


def table_top(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """World z of the task's table top: the highest face of the visible boxes of MetaWorld's ``tablelink``
    body. Read from the model because it differs between tasks (sweep-into's table, holed at the goal, is
    5 cm higher than the common one)."""
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "tablelink")
    if body < 0:
        raise ValueError("this MetaWorld scene has no 'tablelink' body; pass table_clearance=None")
    tops = [
        data.geom_xpos[g][2] + np.abs(data.geom_xmat[g].reshape(3, 3)[2]) @ model.geom_size[g]
        for g in range(model.ngeom)
        if model.geom_bodyid[g] == body and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX
        and model.geom_group[g] < 3  # rendered geoms only; groups 3-5 are collision proxies
    ]
    if not tops:
        raise ValueError("MetaWorld's 'tablelink' body has no visible box; pass table_clearance=None")
    return float(max(tops))


def above_table(spec: PointCloudSpec, top: float, clearance: float) -> PointCloudSpec:
    """``spec`` with its box's lower z raised to ``clearance`` above the table top (never lowered)."""
    low = (*spec.bounds.low[:2], max(spec.bounds.low[2], top + clearance))
    return replace(spec, bounds=WorkspaceBounds(low, spec.bounds.high))


class FocalMetaworldEnv(MetaworldEnv):
    """One MetaWorld v3 task; ``obs_type`` in {state, pointcloud, pixels, pixels_agent_pos}."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 80}

    def __init__(
        self,
        task: str,
        obs_type: str = "pointcloud",
        camera_name: str = "corner2",
        camera_pos: tuple[float, float, float] | None = DP3_CORNER2_POS,
        episode_length: int = 200,
        observation_width: int = 128,
        observation_height: int = 128,
        num_points: int = 512,
        depth_width: int = 128,
        depth_height: int = 128,
        workspace_low: tuple[float, float, float] = DEFAULT_WORKSPACE_LOW,
        workspace_high: tuple[float, float, float] = DEFAULT_WORKSPACE_HIGH,
        voxel_size: float = DEFAULT_VOXEL_SIZE,
        raycast_threads: int | None = None,
        visualization_width: int = 640,
        visualization_height: int = 480,
        metrics_path: str | None = None,
        cheap_rendering: bool = True,
        draw_sites: bool = True,
        env_state: bool = False,
        render_videos: bool = True,
        table_clearance: float | None = DEFAULT_TABLE_CLEARANCE,
        reset_seed_offset: int = 0,
        gripper_levels: tuple[float, float] | None = None,
    ) -> None:
        check_obs_type(obs_type)
        # The gripper command snapped to the nearer of two levels (FocalMetaworldEnvConfig.gripper_levels).
        self.gripper_levels = None if gripper_levels is None else np.asarray(gripper_levels, dtype=np.float32)
        # Added to every reset seed (placements): lets one evaluation draw other placements than the last one
        # although LeRobot resets with the same seeds each time (see FocalMetaworldEnvConfig.fresh_reset_seeds).
        self.reset_seed_offset = reset_seed_offset
        # LeRobot's constructor only accepts its own pixel obs types; build as "pixels", then take over.
        super().__init__(
            task=task,
            camera_name=camera_name,
            obs_type="pixels",
            render_mode="rgb_array",
            observation_width=observation_width,
            observation_height=observation_height,
            visualization_width=visualization_width,
            visualization_height=visualization_height,
        )
        self.obs_type = obs_type
        self.env_state = env_state
        self.camera_pos = camera_pos
        self._max_episode_steps = episode_length
        self.pointcloud_spec = PointCloudSpec(
            num_points=num_points, bounds=WorkspaceBounds(workspace_low, workspace_high), voxel_size=voxel_size
        )
        self.table_clearance = table_clearance
        self.depth_size = (depth_height, depth_width)
        self.raycast_threads = raycast_threads
        self._pc_sensor: RayCastPointCloudSensor | None = None
        self.metrics = EpisodeMetrics(self.task, metrics_path)
        self.cheap_rendering = cheap_rendering
        self.draw_sites = draw_sites
        self.render_videos = render_videos
        self._viewer_ready = False
        self.last_raw_obs: np.ndarray | None = None  # MetaWorld's 39-d observation, what its experts read
        #: MetaWorld's own ``grasp_success`` at the last step (False after reset): the object is held.
        self.object_grasped = False

        obs_spaces: dict[str, spaces.Space] = {}
        if uses_state(obs_type):
            obs_spaces[AGENT_POS_KEY] = spaces.Box(-1000.0, 1000.0, (METAWORLD_STATE_DIM,), np.float32)
        if uses_pointcloud(obs_type):
            obs_spaces[POINTCLOUD_KEY] = spaces.Box(-10.0, 10.0, (num_points, 3), np.float32)
        if uses_pixels(obs_type):
            obs_spaces[PIXELS_KEY] = spaces.Box(0, 255, (observation_height, observation_width, 3), np.uint8)
        if env_state:
            obs_spaces[ENV_STATE_KEY] = spaces.Box(-np.inf, np.inf, (METAWORLD_ENV_STATE_DIM,), np.float32)
        self.observation_space = spaces.Dict(obs_spaces)

    def _ensure_env(self) -> None:
        """LeRobot's lazy construction, plus render size, DP3 camera pose, and the episode length.

        Kept lazy (first reset) as in LeRobot so AsyncVectorEnv workers build their own MuJoCo state.
        """
        if self._env is not None:
            return
        env_class, task = metaworld_task(self._env_name)
        env = env_class(
            render_mode="rgb_array",
            camera_name=self.camera_name,
            width=self.observation_width,
            height=self.observation_height,
        )
        env.set_task(task)
        env.max_path_length = self._max_episode_steps  # MetaWorld then reports truncated at this step
        if self.camera_pos is not None:
            cam_id = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_CAMERA, self.camera_name)
            env.model.cam_pos[cam_id] = self.camera_pos
        env.reset()
        env._freeze_rand_vec = False  # otherwise every reset has the same object positions
        env.seeded_rand_vec = True  # reset(seed=X) controls object positions
        self._env = env
        if uses_pointcloud(self.obs_type):
            if self.table_clearance is not None:
                self.pointcloud_spec = above_table(self.pointcloud_spec, table_top(env.model, env.data),
                                                   self.table_clearance)
            self._pc_sensor = RayCastPointCloudSensor(
                env.model,
                self.camera_name,
                self.pointcloud_spec,
                width=self.depth_size[1],
                height=self.depth_size[0],
                num_threads=self.raycast_threads,
                site_groups=RENDERED_SITE_GROUPS if self.draw_sites else None,
            )

    def agent_pos(self) -> np.ndarray:
        """DP3's 9-d state: hand position, then right and left finger-pad sites."""
        data = self._env.data
        return np.concatenate(
            [
                self._env.get_endeff_pos(),
                data.site("rightEndEffector").xpos,
                data.site("leftEndEffector").xpos,
            ]
        ).astype(np.float32)

    def pointcloud(self) -> np.ndarray:
        assert self._pc_sensor is not None, "point cloud requested but obs_type is not 'pointcloud'"
        return self._pc_sensor(self._env.data)

    def render(self) -> np.ndarray:
        """RGB frame of ``camera_name`` (LeRobot's orientation fix for corner2), shadows off by default."""
        if not self.render_videos:
            return np.zeros((16, 16, 3), dtype=np.uint8)  # see FocalMetaworldEnvConfig.render_videos
        self._ensure_env()
        if not self._viewer_ready:
            if self.cheap_rendering:
                make_rendering_cheap(self._env.mujoco_renderer)
            self._viewer_ready = True
        return super().render()

    def expert_action(self) -> np.ndarray:
        """MetaWorld's scripted expert (``metaworld.policies``) for the current state, clipped to [-1, 1]."""
        if self.last_raw_obs is None:
            raise RuntimeError("reset the env before asking the expert for an action")
        return np.clip(self.expert_policy.get_action(self.last_raw_obs), -1.0, 1.0).astype(np.float32)

    def _format_raw_obs(self, raw_obs: np.ndarray) -> dict[str, Any]:
        self.last_raw_obs = np.asarray(raw_obs, dtype=np.float64)
        obs: dict[str, Any] = {}
        if uses_state(self.obs_type):
            obs[AGENT_POS_KEY] = self.agent_pos()
        if uses_pointcloud(self.obs_type) or uses_pixels(self.obs_type):
            # Draw the state as it is now. MetaWorld's reset moves the goal site (model.site_pos) after its last
            # forward pass, so without this the first frame of an episode drew the goal marker where it was
            # before the reset; after a step it brings the poses from the last substep's start to its end.
            mujoco.mj_kinematics(self._env.model, self._env.data)
        if uses_pointcloud(self.obs_type):
            obs[POINTCLOUD_KEY] = self.pointcloud()
        if uses_pixels(self.obs_type):
            obs[PIXELS_KEY] = np.ascontiguousarray(self.render())
        if self.env_state:
            obs[ENV_STATE_KEY] = self.last_raw_obs.astype(np.float32)
        return obs

    def reset(self, seed: int | None = None, **kwargs) -> tuple[dict[str, Any], dict[str, Any]]:
        if seed is not None:
            seed += self.reset_seed_offset  # the seed recorded below is the one that placed the objects
        observation, info = super().reset(seed=seed, **kwargs)
        self.metrics.start(seed)
        self.object_grasped = False
        return observation, info

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """LeRobot's success semantics (terminate on first success, ``final_info``), plus episode metrics.

        Unlike LeRobot's ``MetaworldEnv`` this does not reset itself at termination: vector envs autoreset,
        and a single env is reset by its caller, so the terminal observation stays the real one.
        """
        self._ensure_env()
        action = np.asarray(action, dtype=np.float32)
        if action.shape != self.action_space.shape:
            raise ValueError(f"expected an action of shape {self.action_space.shape}, got {action.shape}")
        if self.gripper_levels is not None:
            action = action.copy()
            action[3] = self.gripper_levels[np.argmin(np.abs(self.gripper_levels - action[3]))]
        self.metrics.step(action)
        raw_obs, reward, done, truncated, info = self._env.step(action)
        is_success = bool(info.get("success", 0))
        self.object_grasped = bool(info.get("grasp_success", 0))
        terminated = bool(done) or is_success
        truncated = bool(truncated)
        info = {**info, "task": self.task, "done": bool(done), "is_success": is_success}
        observation = self._format_raw_obs(raw_obs)
        if terminated or truncated:
            record = self.metrics.finish(is_success)
            info["action_total_variation"] = record["action_total_variation"]
            info["final_info"] = {
                "task": self.task,
                "done": True,
                "is_success": is_success,
                "action_total_variation": record["action_total_variation"],
            }
        return observation, float(reward), terminated, truncated, info

    def close(self) -> None:
        if self._pc_sensor is not None:
            self._pc_sensor.close()
        super().close()
