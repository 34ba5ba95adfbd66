"""The `focal_depth_to_pointcloud` processor step: a depth frame becomes the policy's point cloud.

For robots such as `ur10e` that record `observation.images.<cam>_depth` (LeRobot 0.6.1 cannot record a point
cloud), `FocalConfig.depth_cloud.from_depth` adds this registered step to the preprocessor. It runs after "add
batch dim" and builds `observation.pointcloud` with the same `lerobot_focal.geometry.pointcloud` code the
simulated benchmarks use. Its config (camera intrinsics + extrinsics, crop box, size, units) is saved in
`policy_preprocessor.json`, so `lerobot-rollout --policy.path=…` rebuilds the identical step; the camera info
is found here (`resolve_camera_info_path`), from the `cameras.json` the robot writes on connect.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lerobot.configs.types import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry

from lerobot_focal.constants import OBS_POINTCLOUD
from lerobot_focal.policy.configuration_focal import FocalConfig

logger = logging.getLogger(__name__)

DEPTH_TO_POINTCLOUD_STEP = "focal_depth_to_pointcloud"
_CAMERA_INFO_KEYS = ("width", "height", "fx", "fy", "cx", "cy", "T_base_cam")


@ProcessorStepRegistry.register(DEPTH_TO_POINTCLOUD_STEP)
@dataclass
class DepthToPointCloudProcessorStep(ObservationProcessorStep):
    """Depth map → (num_points, 3) base-frame point cloud: back-projection → crop → (voxel grid) → FPS.

    The same functions as the simulated benchmarks (`lerobot_focal.geometry.pointcloud.depth_to_pointcloud`), for
    every form a depth frame reaches a policy preprocessor in:

    * live, from `lerobot-rollout`: the robot's raw frame, an integer (uint16) tensor (B, 1, H, W) (or (H, W),
      (H, W, 1), (1, H, W), …) in sensor units; metres = value × ``camera_info["depth_scale"]`` (0.001: mm);
    * from a dataset during `lerobot-train`: LeRobot's decoded depth video, float32 (B, n_obs, 1, H, W) in
      ``float_depth_unit`` ("mm", LeRobot's default; "m" with `--dataset.depth_output_unit=m`). LeRobot stores
      the raw frame as its "mm", so "mm" floats are scaled like raw integers.

    Leading (batch, time) dimensions are kept: the output is float32 ``(*lead, num_points, 3)`` on the input's
    device. The depth key stays in the observation (the policy ignores it).

    ``camera_info`` is the robot's `cameras.json` entry (`lerobot_focal.robots.ur10e.camera_info.CameraInfo`):
    width, height, fx, fy, cx, cy of the depth image, ``T_base_cam`` (4×4, OpenCV optical frame in the robot
    base frame) and ``depth_scale``.
    """

    depth_key: str = "observation.images.front_depth"
    pointcloud_key: str = OBS_POINTCLOUD
    camera_info: dict[str, Any] = field(default_factory=dict)
    crop_min: list[float] = field(default_factory=lambda: [-1.0, -1.0, -1.0])
    crop_max: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])
    num_points: int = 512
    voxel_size: float = 0.0
    float_depth_unit: str = "mm"
    # Depths below this (metres) count as "no return". LeRobot's depth codec decodes a 0 (no return) as its
    # depth_min, 10 mm by default, while the live frame has 0: without this the two would differ.
    min_depth: float = 0.05

    def __post_init__(self) -> None:
        from lerobot_focal.geometry.pointcloud import PinholeIntrinsics, PointCloudSpec, WorkspaceBounds

        missing = [k for k in _CAMERA_INFO_KEYS if k not in self.camera_info]
        if missing:
            raise ValueError(
                f"{DEPTH_TO_POINTCLOUD_STEP}: camera_info for '{self.depth_key}' lacks {missing}. It must be one "
                "camera's entry of the cameras.json the ur10e robot writes on connect "
                "($HF_LEROBOT_CALIBRATION/robots/ur10e/<id>_cameras.json): width, height, fx, fy, cx, cy, "
                "T_base_cam (4x4) and depth_scale."
            )
        if self.float_depth_unit not in ("mm", "m"):
            raise ValueError(f"float_depth_unit must be 'mm' or 'm', got {self.float_depth_unit!r}.")
        info = self.camera_info
        self.camera_info = {
            **{k: info[k] for k in ("width", "height")},
            **{k: float(info[k]) for k in ("fx", "fy", "cx", "cy")},
            "T_base_cam": [[float(x) for x in row] for row in info["T_base_cam"]],
            "depth_scale": float(info.get("depth_scale", 0.001)),
        }
        self.crop_min = [float(x) for x in self.crop_min]
        self.crop_max = [float(x) for x in self.crop_max]
        self._intrinsics = PinholeIntrinsics(
            fx=self.camera_info["fx"],
            fy=self.camera_info["fy"],
            cx=self.camera_info["cx"],
            cy=self.camera_info["cy"],
            width=int(self.camera_info["width"]),
            height=int(self.camera_info["height"]),
        )
        self._pose = np.asarray(self.camera_info["T_base_cam"], dtype=np.float64)
        if self._pose.shape != (4, 4):
            raise ValueError(f"camera_info T_base_cam must be 4x4, got shape {self._pose.shape}.")
        self._spec = PointCloudSpec(
            num_points=int(self.num_points),
            bounds=WorkspaceBounds(tuple(self.crop_min), tuple(self.crop_max)),
            voxel_size=float(self.voxel_size),
        )
        self._last_empty_warning = -np.inf

    # --- the conversion ------------------------------------------------------------------------------------
    def _split(self, depth: np.ndarray) -> tuple[tuple[int, ...], np.ndarray]:
        """(lead dims, (N, H, W) frames) from any of (…, H, W), (…, 1, H, W), (…, H, W, 1)."""
        h, w = self._intrinsics.height, self._intrinsics.width
        shape = depth.shape
        if depth.ndim >= 3 and shape[-3:] == (1, h, w):
            lead = shape[:-3]
        elif depth.ndim >= 3 and shape[-3:] == (h, w, 1):
            lead = shape[:-3]
        elif depth.ndim >= 2 and shape[-2:] == (h, w):
            lead = shape[:-2]
        else:
            raise ValueError(
                f"{DEPTH_TO_POINTCLOUD_STEP}: '{self.depth_key}' has shape {tuple(shape)}, but the camera info is "
                f"for {h}x{w} depth frames. The camera_info (cameras.json) must come from the camera that "
                "recorded this depth, at the same resolution (and rotation 0)."
            )
        return lead, depth.reshape(-1, h, w)

    def metres_per_unit(self, dtype: np.dtype) -> float:
        """Scale from the frame's values to metres: raw sensor units for integers, `float_depth_unit` for floats."""
        raw = self.camera_info["depth_scale"]
        if np.issubdtype(dtype, np.integer):
            return raw
        # LeRobot stores the raw frame as "mm" and decodes it to float mm, or to metres = mm / 1000.
        return raw if self.float_depth_unit == "mm" else raw * 1000.0

    def depth_to_points(self, depth: np.ndarray | torch.Tensor) -> np.ndarray:
        """float32 (*lead, num_points, 3) point cloud(s) from a depth array/tensor of any supported layout."""
        if isinstance(depth, torch.Tensor):
            depth = depth.detach().cpu().numpy()
        depth = np.asarray(depth)
        lead, frames = self._split(depth)
        scale = self.metres_per_unit(depth.dtype)
        if not np.issubdtype(depth.dtype, np.integer) and self.float_depth_unit == "mm" and frames.size:
            valid = frames[frames > 0]
            if valid.size and float(np.median(valid)) < 20.0:
                raise ValueError(
                    f"{DEPTH_TO_POINTCLOUD_STEP}: '{self.depth_key}' looks like metres "
                    f"(median {np.median(valid):.3g}), "
                    "but float depth is read as millimetres. Train without --dataset.depth_output_unit=m, or set "
                    "--policy.depth_cloud.depth_unit=m."
                )
        clouds = np.stack([self._one(f, scale) for f in frames])
        if not np.any(clouds):
            self._warn_empty()
        return clouds.reshape(*lead, self._spec.num_points, 3)

    def _one(self, frame: np.ndarray, scale: float) -> np.ndarray:
        from lerobot_focal.geometry.pointcloud import depth_to_pointcloud

        return depth_to_pointcloud(
            frame, self._intrinsics, self._pose, self._spec, depth_scale=scale, min_depth=self.min_depth
        )

    def _warn_empty(self) -> None:
        now = time.monotonic()
        if now - self._last_empty_warning > 10.0:
            self._last_empty_warning = now
            logger.warning(
                "%s: no depth point of '%s' lies inside the crop box %s..%s: the point cloud is all zeros. Check "
                "the camera pose (T_base_cam), the crop box and the depth unit.",
                DEPTH_TO_POINTCLOUD_STEP, self.depth_key, self.crop_min, self.crop_max,
            )

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        if self.depth_key not in observation:
            raise KeyError(
                f"{DEPTH_TO_POINTCLOUD_STEP}: the observation has no '{self.depth_key}', from which this policy "
                f"builds '{self.pointcloud_key}'. "
                f"Present: {sorted(k for k in observation if k.startswith('observation'))}. "
                "Run the robot with that depth camera (ur10e: a RealSense camera with use_depth: true; the sim "
                "backend always provides front_depth), or map your key to it with --rename_map."
            )
        depth = observation[self.depth_key]
        points = torch.from_numpy(self.depth_to_points(depth))
        if isinstance(depth, torch.Tensor):
            points = points.to(depth.device)
        observation[self.pointcloud_key] = points
        return observation

    # --- LeRobot processor protocol ------------------------------------------------------------------------
    def get_config(self) -> dict[str, Any]:
        return {
            "depth_key": self.depth_key,
            "pointcloud_key": self.pointcloud_key,
            "camera_info": self.camera_info,
            "crop_min": self.crop_min,
            "crop_max": self.crop_max,
            "num_points": int(self.num_points),
            "voxel_size": float(self.voxel_size),
            "float_depth_unit": self.float_depth_unit,
            "min_depth": float(self.min_depth),
        }

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        obs = dict(features.get(PipelineFeatureType.OBSERVATION, {}))
        obs[self.pointcloud_key] = PolicyFeature(type=FeatureType.STATE, shape=(int(self.num_points), 3))
        return {**features, PipelineFeatureType.OBSERVATION: obs}


def _recording_camera_files(robot_type: str | None) -> list[Path]:
    """The cameras.json files the dataset's robot type wrote on connect, here (one per robot id)."""
    if not robot_type:
        return []
    from lerobot.utils.constants import HF_LEROBOT_CALIBRATION

    return sorted((HF_LEROBOT_CALIBRATION / "robots" / robot_type).glob("*_cameras.json"))


def resolve_camera_info_path(config: FocalConfig) -> Path:
    """Where the depth camera's intrinsics and pose come from: `depth_cloud.camera_info`, else the dataset's
    `meta/cameras.json`, else the one file the dataset's robot type wrote when it connected to record.

    The last is the usual case (record, then train on the machine that recorded): no file is copied by hand, and
    the checkpoint keeps what was read in its `focal_depth_to_pointcloud` step.
    """
    settings = config.depth_cloud
    if settings.camera_info:
        path = Path(settings.camera_info).expanduser()
        if not path.is_file():
            raise FileNotFoundError(
                f"--policy.depth_cloud.camera_info={settings.camera_info}: no such file. It is the "
                "cameras.json the ur10e robot writes on every connect to "
                "$HF_LEROBOT_CALIBRATION/robots/ur10e/<robot id or ur10e>_cameras.json."
            )
        return path
    meta = getattr(config, "_runtime_dataset_meta", None)  # set by LeRobot's make_policy
    root = getattr(meta, "root", None)
    if root is not None and (Path(root) / "meta" / "cameras.json").is_file():
        return Path(root) / "meta" / "cameras.json"
    robot_type = getattr(meta, "robot_type", None)
    recorded = _recording_camera_files(robot_type)
    if len(recorded) == 1:
        logger.info("depth camera intrinsics and pose for %s: %s (written by the %s robot on connect)",
                    settings.from_depth, recorded[0], robot_type)
        return recorded[0]
    if recorded:
        raise FileNotFoundError(
            f"depth_cloud.from_depth={settings.from_depth!r}: the dataset was recorded by a {robot_type!r} robot, "
            f"and robots of that type wrote several camera files here: {[str(p) for p in recorded]}. Pass the one "
            "of the robot (its --robot.id) that recorded it as --policy.depth_cloud.camera_info=<path>."
        )
    where = f"{Path(root) / 'meta' / 'cameras.json'} does not exist" if root is not None else "no dataset is known"
    raise FileNotFoundError(
        f"depth_cloud.from_depth={settings.from_depth!r} needs the depth camera's intrinsics and pose, "
        f"which LeRobot does not store ({where}, and no {robot_type or 'robot'} camera file is in "
        "$HF_LEROBOT_CALIBRATION/robots/<robot type>/). The ur10e robot writes them on every connect to "
        "$HF_LEROBOT_CALIBRATION/robots/ur10e/<robot id or ur10e>_cameras.json (default ~/.cache/huggingface/"
        "lerobot/calibration): train where the dataset was recorded, pass "
        "--policy.depth_cloud.camera_info=<path to that file>, or put it at <dataset root>/meta/cameras.json."
    )


def make_depth_to_pointcloud_step(config: FocalConfig) -> DepthToPointCloudProcessorStep:
    """The step for `config.depth_cloud`, with the camera info read from cameras.json."""
    settings = config.depth_cloud
    path = resolve_camera_info_path(config)
    infos = json.loads(path.read_text())
    camera = settings.camera_name
    if camera not in infos:
        raise KeyError(
            f"{path} has no camera {camera!r} (it has {sorted(infos)}), needed for "
            f"'{settings.from_depth}'. Pass --policy.depth_cloud.camera=<one of those>."
        )
    return DepthToPointCloudProcessorStep(
        depth_key=settings.from_depth,
        pointcloud_key=config.pointcloud_key,
        camera_info=infos[camera],
        crop_min=list(settings.crop_min),
        crop_max=list(settings.crop_max),
        num_points=settings.num_points,
        voxel_size=settings.voxel_size,
        float_depth_unit=settings.depth_unit,
        min_depth=settings.min_depth,
    )
