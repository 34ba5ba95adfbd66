"""Camera intrinsics/extrinsics and the single call site that turns depth into a point cloud.

LeRobot 0.6.1's RealSense camera drops the intrinsics at capture, so a stored depth map cannot be unprojected
later. This stack keeps them itself (from the simulated camera's model or the RealSense depth stream
profile) in a :class:`CameraInfo`, which is JSON-serialisable so it can be written next to the dataset.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class CameraInfo:
    """Pinhole intrinsics of the *depth* image plus the camera pose in the robot base frame.

    `T_base_cam` uses the OpenCV optical convention (x right, y down, z forward), the convention of both the
    RealSense SDK and :func:`depth_to_pointcloud`. `depth_scale` converts stored depth units to metres
    (0.001 for the uint16 millimetres LeRobot and the RealSense use).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    T_base_cam: tuple[tuple[float, ...], ...]
    depth_scale: float = 0.001

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> CameraInfo:
        data = dict(data)
        data["T_base_cam"] = tuple(tuple(float(x) for x in row) for row in data["T_base_cam"])
        return cls(**data)

    @property
    def extrinsic(self) -> np.ndarray:
        return np.asarray(self.T_base_cam, dtype=np.float64)


def pose_matrix(pos: np.ndarray, rot: np.ndarray) -> tuple[tuple[float, ...], ...]:
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = pos
    return tuple(tuple(float(x) for x in row) for row in t)


def depth_to_pointcloud(
    depth: np.ndarray,
    info: CameraInfo,
    crop_min: tuple[float, float, float],
    crop_max: tuple[float, float, float],
    num_points: int = 512,
) -> np.ndarray:
    """(num_points, 3) float32 point cloud in the robot base frame from a depth map in `info.depth_scale` units.

    The one place the robot turns depth into points: it delegates to the project's shared implementation
    (`lerobot_focal.geometry.pointcloud`, same conventions) so simulation, datasets and the real arm use the same
    code path.
    """
    from lerobot_focal.geometry.pointcloud import (
        PinholeIntrinsics,
        PointCloudSpec,
        WorkspaceBounds,
        depth_to_pointcloud as shared_depth_to_pointcloud,
    )

    intr = PinholeIntrinsics(
        fx=info.fx, fy=info.fy, cx=info.cx, cy=info.cy, width=info.width, height=info.height
    )
    spec = PointCloudSpec(
        num_points=num_points,
        bounds=WorkspaceBounds(tuple(map(float, crop_min)), tuple(map(float, crop_max))),
    )
    depth2d = np.asarray(depth).reshape(info.height, info.width)
    return shared_depth_to_pointcloud(depth2d, intr, info.extrinsic, spec, depth_scale=info.depth_scale)


def save_camera_infos(path, infos: dict[str, CameraInfo]) -> None:
    """Write {camera: CameraInfo} as JSON, e.g. to `<dataset root>/meta/cameras.json` next to the depth videos."""
    import json
    from pathlib import Path

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps({k: v.to_dict() for k, v in infos.items()}, indent=2))


def load_camera_infos(path) -> dict[str, CameraInfo]:
    import json
    from pathlib import Path

    return {k: CameraInfo.from_dict(v) for k, v in json.loads(Path(path).read_text()).items()}
