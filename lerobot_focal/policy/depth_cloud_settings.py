"""`DepthCloudConfig`: how a deployed focal policy turns a depth frame into its point cloud (`--policy.depth_cloud.*`).

These settings are the only copy: the preprocessor's `focal_depth_to_pointcloud` step is built from them
(`depth_pointcloud_step.make_depth_to_pointcloud_step`) and saves them, with the camera's intrinsics, in the
checkpoint, so `lerobot-eval` and `lerobot-rollout` make the clouds the policy trained on. Robots record depth;
they do not crop or sample clouds. A nested config, as LeRobot's own policies nest theirs (``rtc_config``): one
``--policy.depth_cloud.from_depth=…`` turns the whole group on, and the rest of `FocalConfig` stays the method's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_focal.config_errors import require_non_negative, require_positive


@dataclass
class DepthCloudConfig:
    """Depth → point cloud in the preprocessor: back-projection → crop → (voxel grid) → farthest point sampling.

    Args:
        from_depth: A depth key (e.g. "observation.images.front_depth") to turn into the point cloud, for robots
            such as `ur10e` that record depth because LeRobot cannot record a point cloud. It adds the policy's
            `pointcloud_key` (P, 3) to the input features and a `focal_depth_to_pointcloud` step to the
            preprocessor (`lerobot_focal.geometry.pointcloud`), identical at training (decoded depth video) and at
            rollout (the robot's raw uint16 frame). None: the policy reads a recorded cloud, if any.
        camera_info: cameras.json with the depth camera's intrinsics and pose. None → the dataset's
            `meta/cameras.json`, else the file the dataset's robot wrote when it connected to record
            ($HF_LEROBOT_CALIBRATION/robots/<robot_type>/<id>_cameras.json), found from the dataset's robot type.
        camera: Entry of that file; None → derived from the depth key ("…front_depth" → "front").
        crop_min: Lower corner of the workspace box the cloud is cropped to (robot base frame, metres).
        crop_max: Upper corner of that box.
        num_points: Points kept by farthest-point sampling.
        voxel_size: > 0: voxel-grid downsampling before sampling (faster on large frames).
        depth_unit: Unit of *float* depth from a decoded dataset ("mm", LeRobot's default
            `--dataset.depth_output_unit`, or "m"); integer frames (the robot's raw uint16) are raw sensor units
            times the camera's depth_scale.
        min_depth: Depths below this (m) count as "no return" (LeRobot's codec decodes 0 as 10 mm).
    """

    from_depth: str | None = None
    camera_info: str | None = None
    camera: str | None = None
    crop_min: tuple[float, float, float] | None = None
    crop_max: tuple[float, float, float] | None = None
    num_points: int = 512
    voxel_size: float = 0.0
    depth_unit: str = "mm"
    min_depth: float = 0.05

    @property
    def enabled(self) -> bool:
        return self.from_depth is not None

    def validate(self) -> None:
        """Refuse settings that cannot make a cloud, naming the fix (a ValueError reaches the CLI user)."""
        require_positive(**{"depth_cloud.num_points": self.num_points})
        require_non_negative(**{"depth_cloud.voxel_size": self.voxel_size, "depth_cloud.min_depth": self.min_depth})
        if self.depth_unit not in ("mm", "m"):
            raise ValueError(f"depth_cloud.depth_unit must be 'mm' or 'm', got {self.depth_unit!r}.")
        if not self.enabled:
            return
        if self.crop_min is None or self.crop_max is None:
            raise ValueError(
                f"depth_cloud.from_depth={self.from_depth!r} needs the workspace box the cloud is cropped to, in the "
                "robot base frame (metres): pass --policy.depth_cloud.crop_min='[x,y,z]' and "
                "--policy.depth_cloud.crop_max='[x,y,z]', a box around the table top and the objects on it that "
                "leaves the floor and the robot's base out (docs/robot.md: choosing the box)."
            )
        lo, hi = tuple(self.crop_min), tuple(self.crop_max)
        if len(lo) != 3 or len(hi) != 3 or any(a >= b for a, b in zip(lo, hi, strict=True)):
            raise ValueError(f"depth_cloud.crop_min {lo} must be below depth_cloud.crop_max {hi} on x, y and z.")

    @property
    def camera_name(self) -> str | None:
        """Camera whose intrinsics unproject `from_depth` ("observation.images.front_depth" → "front")."""
        if self.camera:
            return self.camera
        if self.from_depth is None:
            return None
        name = self.from_depth.rsplit(".", 1)[-1]
        return name[: -len("_depth")] if name.endswith("_depth") else name

    def cloud_feature(self) -> PolicyFeature:
        return PolicyFeature(type=FeatureType.STATE, shape=(self.num_points, 3))


def validate_depth_cloud(config: Any) -> None:
    """The depth settings of a policy config, with what they need from the rest of it."""
    settings: DepthCloudConfig = config.depth_cloud
    settings.validate()
    if not settings.enabled:
        return
    if not config.use_pointcloud:
        raise ValueError("depth_cloud.from_depth is set but use_pointcloud=false: drop one of the two.")
    if config.use_pointcloud_color:
        raise ValueError("depth_cloud.from_depth makes an xyz (P, 3) cloud; use_pointcloud_color needs (P, 6).")
    # A config loaded from a checkpoint already lists the cloud; one from the command line gets it from the
    # dataset hook (declare_cloud_input), or here when input features were given explicitly.
    if config.input_features and config.pointcloud_key not in config.input_features:
        config.input_features[config.pointcloud_key] = settings.cloud_feature()


def declare_cloud_input(config: Any, features: dict) -> None:
    """With `depth_cloud.from_depth`, the dataset holds depth but no point cloud: check the depth key is there and
    declare `pointcloud_key` as an input, so the policy is built for it and `config.json` lists it."""
    key = config.depth_cloud.from_depth
    if key is None:
        return
    if key not in features:
        depth = [k for k, ft in features.items() if (ft.get("info") or {}).get("is_depth_map")]
        raise ValueError(
            f"depth_cloud.from_depth={key!r} is not a feature of the dataset. Its depth features are {depth}; "
            "pass one of them as --policy.depth_cloud.from_depth (or record depth: for ur10e, a RealSense "
            "camera with use_depth: true; the sim backend always records `front_depth`)."
        )
    config.input_features[config.pointcloud_key] = config.depth_cloud.cloud_feature()
