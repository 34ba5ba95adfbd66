"""The deployed depth → point cloud settings of a focal config (``pointcloud_from_depth`` and the fields that go
with it): their checks, the camera they read, and the cloud they declare as an input.

These are the only copy of those settings: the preprocessor's `focal_depth_to_pointcloud` step is built from
them (`depth_pointcloud_step.make_depth_to_pointcloud_step`) and saves them, with the camera's intrinsics, in the
checkpoint, so `lerobot-eval` and `lerobot-rollout` make the clouds the policy trained on. Robots record depth;
they do not crop or sample clouds.
"""

from __future__ import annotations

from typing import Any

from lerobot.configs.types import FeatureType, PolicyFeature


def validate_depth_cloud(config: Any) -> None:
    """Refuse settings that cannot make a cloud, naming the fix (a ValueError reaches the CLI user)."""
    if config.pointcloud_crop_min is None or config.pointcloud_crop_max is None:
        raise ValueError(
            f"pointcloud_from_depth={config.pointcloud_from_depth!r} needs the workspace box the cloud is cropped "
            "to, in the robot base frame (metres): pass --policy.pointcloud_crop_min='[x,y,z]' and "
            "--policy.pointcloud_crop_max='[x,y,z]', a box around the table top and the objects on it that leaves "
            "the floor and the robot's base out (docs/robot.md: choosing the box)."
        )
    lo, hi = tuple(config.pointcloud_crop_min), tuple(config.pointcloud_crop_max)
    if len(lo) != 3 or len(hi) != 3 or any(a >= b for a, b in zip(lo, hi, strict=True)):
        raise ValueError(f"pointcloud_crop_min {lo} must be below pointcloud_crop_max {hi} on x, y and z.")
    if not config.use_pointcloud:
        raise ValueError("pointcloud_from_depth is set but use_pointcloud=false: drop one of the two.")
    if config.use_pointcloud_color:
        raise ValueError("pointcloud_from_depth makes an xyz (P, 3) cloud; use_pointcloud_color needs (P, 6).")
    # A config loaded from a checkpoint already lists the cloud; one from the command line gets it from the
    # dataset hook (declare_cloud_input), or here when input features were given explicitly.
    if config.input_features and config.pointcloud_key not in config.input_features:
        config.input_features[config.pointcloud_key] = cloud_feature(config)


def camera_name(config: Any) -> str | None:
    """Camera whose intrinsics unproject `pointcloud_from_depth` ("observation.images.front_depth" → "front")."""
    if config.pointcloud_camera:
        return config.pointcloud_camera
    if config.pointcloud_from_depth is None:
        return None
    name = config.pointcloud_from_depth.rsplit(".", 1)[-1]
    return name[: -len("_depth")] if name.endswith("_depth") else name


def cloud_feature(config: Any) -> PolicyFeature:
    return PolicyFeature(type=FeatureType.STATE, shape=(config.pointcloud_num_points, 3))


def declare_cloud_input(config: Any, features: dict) -> None:
    """With `pointcloud_from_depth`, the dataset holds depth but no point cloud: check the depth key is there and
    declare `pointcloud_key` as an input, so the policy is built for it and `config.json` lists it."""
    key = config.pointcloud_from_depth
    if key is None:
        return
    if key not in features:
        depth = [k for k, ft in features.items() if (ft.get("info") or {}).get("is_depth_map")]
        raise ValueError(
            f"pointcloud_from_depth={key!r} is not a feature of the dataset. Its depth features are {depth}; "
            "pass one of them as --policy.pointcloud_from_depth (or record depth: for ur10e, a RealSense "
            "camera with use_depth: true; the sim backend always records `front_depth`)."
        )
    config.input_features[config.pointcloud_key] = cloud_feature(config)
