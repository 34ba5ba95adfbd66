"""What the focal env configs share: observation types, keys, feature declarations, name checks."""

from __future__ import annotations

from collections.abc import Iterable

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGE, OBS_STATE

OBS_TYPES: tuple[str, ...] = ("state", "pointcloud", "pixels", "pixels_agent_pos")

#: Raw gym observation keys. ``agent_pos`` and ``pixels`` are the names LeRobot's
#: ``preprocess_observation`` maps to ``observation.state`` / ``observation.image``; the point cloud key is
#: picked up by its pass-through of extra keys and checked by ``PointCloudObservationStep``.
AGENT_POS_KEY = "agent_pos"
PIXELS_KEY = "pixels"
POINTCLOUD_KEY = "pointcloud"
#: The simulator's full low-dimensional observation (object poses included); LeRobot maps it to
#: ``observation.environment_state``.
ENV_STATE_KEY = "environment_state"
#: Voxel size (m) before FPS in the sim envs: 0.01 m is about the pixel footprint of a 128x128 view of the
#: table, so it only thins the densest regions, and it keeps pure-numpy FPS inside the 30 obs/s budget.
DEFAULT_VOXEL_SIZE = 0.01
#: Policy-side key of the point cloud.
OBS_POINTCLOUD = "observation.pointcloud"


def check_obs_type(obs_type: str) -> None:
    if obs_type not in OBS_TYPES:
        raise ValueError(f"unknown obs_type {obs_type!r}; valid obs types: {', '.join(OBS_TYPES)}")


def uses_state(obs_type: str) -> bool:
    return obs_type in ("state", "pointcloud", "pixels_agent_pos")


def uses_pixels(obs_type: str) -> bool:
    return obs_type in ("pixels", "pixels_agent_pos")


def uses_pointcloud(obs_type: str) -> bool:
    return obs_type == "pointcloud"


def env_features(
    obs_type: str, action_dim: int, state_dim: int, num_points: int, image_hw: tuple[int, int],
    env_state_dim: int | None = None,
) -> dict[str, PolicyFeature]:
    """Env-side feature declaration (keys = raw env keys), as LeRobot's EnvConfig.features expects."""
    check_obs_type(obs_type)
    features = {ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(action_dim,))}
    if uses_state(obs_type):
        features[AGENT_POS_KEY] = PolicyFeature(type=FeatureType.STATE, shape=(state_dim,))
    if uses_pointcloud(obs_type):
        # LeRobot has no point-cloud feature type; STATE is what it infers for such a key anyway.
        features[POINTCLOUD_KEY] = PolicyFeature(type=FeatureType.STATE, shape=(num_points, 3))
    if uses_pixels(obs_type):
        features[PIXELS_KEY] = PolicyFeature(type=FeatureType.VISUAL, shape=(*image_hw, 3))
    if env_state_dim is not None:
        features[ENV_STATE_KEY] = PolicyFeature(type=FeatureType.ENV, shape=(env_state_dim,))
    return features


def env_features_map() -> dict[str, str]:
    return {
        ACTION: ACTION,
        AGENT_POS_KEY: OBS_STATE,
        PIXELS_KEY: OBS_IMAGE,
        POINTCLOUD_KEY: OBS_POINTCLOUD,
        ENV_STATE_KEY: OBS_ENV_STATE,
    }


def resolve_names(requested: str, valid: Iterable[str], groups: dict[str, list[str]], what: str) -> list[str]:
    """Comma-separated names and/or group names -> validated list; unknown names list the valid ones."""
    valid = list(valid)
    out: list[str] = []
    for item in (t.strip() for t in requested.split(",")):
        if not item:
            continue
        if item in groups:
            out.extend(groups[item])
        elif item in valid:
            out.append(item)
        else:
            raise ValueError(
                f"unknown {what} {item!r}. Valid groups: {', '.join(groups)}; valid {what}s: {', '.join(valid)}"
            )
    if not out:
        raise ValueError(f"no {what} given; valid groups: {', '.join(groups)}; valid {what}s: {', '.join(valid)}")
    return out


def ensure_offscreen_gl() -> str | None:
    """Pick an offscreen OpenGL backend for pixel observations when the user has not chosen one.

    gymnasium's MuJoCo renderer reads ``MUJOCO_GL`` when it creates its viewer; with no display its default
    (GLFW) fails. Prefer EGL (Mesa's surfaceless EGL works without a GPU), then OSMesa. Returns the backend
    in effect (None: no offscreen library found, rendering will fail with MuJoCo's own error).
    """
    import ctypes.util
    import os

    if os.environ.get("MUJOCO_GL"):
        return os.environ["MUJOCO_GL"]
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None
    for backend, lib in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(lib):
            os.environ["MUJOCO_GL"] = backend
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
    return None


def action_total_variation(actions) -> float:
    """ATV = 1/((L-1) d) * sum_t sum_j |a_{t+1}^j - a_t^j| over one episode's executed (L, d) actions."""
    import numpy as np

    a = np.asarray(actions, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] < 2:
        return 0.0
    return float(np.abs(np.diff(a, axis=0)).sum() / ((a.shape[0] - 1) * a.shape[1]))


class EpisodeMetrics:
    """Per-episode record of executed actions -> success, length and Action Total Variation.

    The env calls ``step`` with each executed action and ``finish`` at termination/truncation; finished
    episodes are logged (``logging.info``, visible in ``lerobot-eval``'s output) and, when ``path`` is set,
    appended as one JSON line each to that file (the summary table for ``lerobot-eval`` runs, which keep
    only success and reward themselves).
    """

    def __init__(self, task: str, path: str | None = None) -> None:
        self.task = task
        self.path = path
        self.actions: list = []
        self.seed: int | None = None
        self.finished: list[dict] = []

    def start(self, seed: int | None) -> None:
        self.actions = []
        self.seed = seed

    def step(self, action) -> None:
        import numpy as np

        self.actions.append(np.array(action, dtype=np.float32, copy=True))

    def finish(self, is_success: bool) -> dict:
        import json
        import logging

        record = {
            "task": self.task,
            "seed": self.seed,
            "success": bool(is_success),
            "length": len(self.actions),
            "action_total_variation": action_total_variation(self.actions),
        }
        self.finished.append(record)
        logging.info(
            "focal env episode: task=%s seed=%s success=%s length=%d ATV=%.5f",
            record["task"], record["seed"], record["success"], record["length"], record["action_total_variation"],
        )
        if self.path:
            with open(self.path, "a") as f:
                f.write(json.dumps(record) + "\n")
        self.actions = []
        return record


def make_rendering_cheap(mujoco_renderer) -> None:
    """Turn off shadows and reflections in a gymnasium ``MujocoRenderer``'s offscreen viewer.

    With software OpenGL (Mesa llvmpipe through EGL or OSMesa, the only kind on a GPU-less machine) they
    cost ~8x: a 128x128 MetaWorld frame took 152 ms with them and 18 ms without. Geometry, colours and
    textures are unchanged.
    """
    import mujoco

    viewer = mujoco_renderer._get_viewer(render_mode="rgb_array")
    viewer.scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
    viewer.scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
