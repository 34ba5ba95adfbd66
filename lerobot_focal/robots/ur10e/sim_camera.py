"""A depth + colour camera for the MuJoCo twin: the simulation's ray-cast depth camera, plus flat shading.

Depth comes from :class:`lerobot_focal.sim.raycast_camera.RayCastDepthCamera`, the one ray-cast camera of the
project (the MetaWorld and Adroit point clouds use it too): exact z-depth without OpenGL (without a GPU there is
often no EGL device, and OSMesa costs ~166 ms per 128x128 frame). Colour comes almost for free from the geom
each ray hit, shaded with normals estimated from the depth image: flat-shaded (no textures, shadows or
specular), which is enough for a visual policy to tell objects apart; point clouds, the paper's main modality,
are exact.
"""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_focal.sim.raycast_camera import RayCastDepthCamera

from .camera_info import CameraInfo, pose_matrix

_BACKGROUND = np.array([0.62, 0.7, 0.8])
_LIGHT_DIR = np.array([0.3, -0.5, -0.8])  # in the camera (OpenCV) frame, pointing from the scene to the camera
#: Every geom group, as a real camera sees every surface of the work cell.
_ALL_GEOM_GROUPS = (1,) * mujoco.mjNGROUP


class RayCastCamera:
    """Renders the MuJoCo camera `camera_name` of `model` as RGB uint8 (H, W, 3) and depth uint16 mm (H, W, 1)."""

    def __init__(self, model: mujoco.MjModel, camera_name: str, width: int, height: int, max_depth_m: float = 6.0):
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera_name) < 0:
            raise ValueError(f"Camera {camera_name!r} is not in the MuJoCo model.")
        self.depth_camera = RayCastDepthCamera(
            model, camera_name, width=int(width), height=int(height), max_depth=max_depth_m,
            geom_groups=_ALL_GEOM_GROUPS,
        )
        intr = self.depth_camera.intrinsics
        self.width, self.height = intr.width, intr.height
        self.fx, self.fy, self.cx, self.cy = intr.fx, intr.fy, intr.cx, intr.cy
        self._rays_cv = intr.pixel_rays()  # (H*W, 3), z = 1 in the optical frame
        rgba = model.geom_rgba.copy()
        has_mat = model.geom_matid >= 0
        rgba[has_mat] = model.mat_rgba[model.geom_matid[has_mat]]
        self._geom_rgb = rgba[:, :3]
        self._light = _LIGHT_DIR / np.linalg.norm(_LIGHT_DIR)

    def camera_info(self, data: mujoco.MjData) -> CameraInfo:
        pose = self.depth_camera.pose(data)
        return CameraInfo(
            width=self.width,
            height=self.height,
            fx=float(self.fx),
            fy=float(self.fy),
            cx=float(self.cx),
            cy=float(self.cy),
            T_base_cam=pose_matrix(pose.position, pose.rotation),
            depth_scale=0.001,
        )

    def render(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """Cast the rays against `data` (whose kinematics must be current). Returns (rgb, depth_mm)."""
        z = self.depth_camera.render(data).astype(np.float64)
        hit = z > 0
        depth_mm = np.clip(np.round(z * 1000.0), 0, 65535).astype(np.uint16)[..., None]
        return self._shade(z, hit, self.depth_camera.last_geom_ids), depth_mm

    def close(self) -> None:
        self.depth_camera.close()

    def _shade(self, z: np.ndarray, hit: np.ndarray, geom_ids: np.ndarray) -> np.ndarray:
        gid = np.where(hit, geom_ids, 0)
        base = np.where(hit[..., None], self._geom_rgb[gid], _BACKGROUND)
        pts = self._rays_cv.reshape(self.height, self.width, 3) * z[..., None]
        du = np.gradient(pts, axis=1)
        dv = np.gradient(pts, axis=0)
        normal = np.cross(du, dv)
        norm = np.linalg.norm(normal, axis=-1, keepdims=True)
        normal = np.divide(normal, norm, out=np.zeros_like(normal), where=norm > 1e-12)
        lambert = np.clip(-(normal @ self._light), 0.0, 1.0)
        shade = np.where(hit, 0.45 + 0.55 * lambert, 1.0)
        return np.clip(base * shade[..., None] * 255.0, 0, 255).astype(np.uint8)
