"""A depth + colour camera for the MuJoCo twin made by casting one ray per pixel.

MuJoCo's offscreen renderer needs an OpenGL context; without a GPU there is often no EGL device, and OSMesa
(software GL) costs ~166 ms per 128x128 frame. `mj_multiRay` gives exact z-depth in a few tens of ms and
colour comes almost for free from the hit geom's rgba, shaded with normals estimated from the depth image.
Colour is therefore flat-shaded (no textures, shadows or specular), which is enough for a visual policy to
tell objects apart; point clouds, the paper's main modality, are exact.
"""

from __future__ import annotations

import mujoco
import numpy as np

from .camera_info import CameraInfo, pose_matrix

_BACKGROUND = np.array([0.62, 0.7, 0.8])
_LIGHT_DIR = np.array([0.3, -0.5, -0.8])  # in the camera (OpenCV) frame, pointing from the scene to the camera


class RayCastCamera:
    """Renders the MuJoCo camera `camera_name` of `model` as RGB uint8 (H, W, 3) and depth uint16 mm (H, W, 1)."""

    def __init__(self, model: mujoco.MjModel, camera_name: str, width: int, height: int, max_depth_m: float = 6.0):
        cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera_name)
        if cam_id < 0:
            raise ValueError(f"Camera {camera_name!r} is not in the MuJoCo model.")
        self.model = model
        self.cam_id = cam_id
        self.width, self.height = int(width), int(height)
        self.max_depth_m = max_depth_m
        fovy = np.deg2rad(model.cam_fovy[cam_id])
        self.fy = self.fx = (self.height / 2) / np.tan(fovy / 2)
        self.cx, self.cy = (self.width - 1) / 2, (self.height - 1) / 2
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        # Rays with unit z in the optical frame: mj_multiRay's distance along them *is* the z-depth.
        self._rays_cv = np.stack(
            [(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u, dtype=float)], axis=-1
        ).reshape(-1, 3)
        n = self.width * self.height
        self._geomid = np.zeros(n, dtype=np.int32)
        self._dist = np.zeros(n, dtype=np.float64)
        rgba = model.geom_rgba.copy()
        has_mat = model.geom_matid >= 0
        rgba[has_mat] = model.mat_rgba[model.geom_matid[has_mat]]
        self._geom_rgb = rgba[:, :3]
        self._light = _LIGHT_DIR / np.linalg.norm(_LIGHT_DIR)

    def _pose(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """Camera position and rotation base<-optical (OpenCV axes) from MuJoCo's (x right, y up, -z fwd)."""
        rot = data.cam_xmat[self.cam_id].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
        return data.cam_xpos[self.cam_id].copy(), rot

    def camera_info(self, data: mujoco.MjData) -> CameraInfo:
        pos, rot = self._pose(data)
        return CameraInfo(
            width=self.width,
            height=self.height,
            fx=float(self.fx),
            fy=float(self.fy),
            cx=float(self.cx),
            cy=float(self.cy),
            T_base_cam=pose_matrix(pos, rot),
            depth_scale=0.001,
        )

    def render(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """Cast the rays against `data` (whose kinematics must be current). Returns (rgb, depth_mm)."""
        pos, rot = self._pose(data)
        vec = (self._rays_cv @ rot.T).reshape(-1)
        mujoco.mj_multiRay(
            self.model, data, pos, vec, None, 1, -1, self._geomid, self._dist, len(self._dist), self.max_depth_m
        )
        z = self._dist.reshape(self.height, self.width)
        hit = (z > 0) & (self._geomid.reshape(self.height, self.width) >= 0)
        z = np.where(hit, z, 0.0)
        depth_mm = np.clip(np.round(z * 1000.0), 0, 65535).astype(np.uint16)[..., None]
        rgb = self._shade(z, hit)
        return rgb, depth_mm

    def _shade(self, z: np.ndarray, hit: np.ndarray) -> np.ndarray:
        gid = np.where(hit, self._geomid.reshape(z.shape), 0)
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
