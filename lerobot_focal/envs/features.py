"""Observation types, raw env keys and feature declarations of the focal envs, and task-name checks."""

from __future__ import annotations

from collections.abc import Iterable

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGE, OBS_STATE

from lerobot_focal.constants import OBS_POINTCLOUD

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
