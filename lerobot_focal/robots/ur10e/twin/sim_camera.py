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

from ..camera_info import CameraInfo, pose_matrix

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
        # Normalised image coordinates of each column / row: the optical-frame ray of pixel (v, u) is (x_u, y_v, 1).
        self._x = ((np.arange(self.width) - self.cx) / self.fx).astype(np.float32)[None, :]
        self._y = ((np.arange(self.height) - self.cy) / self.fy).astype(np.float32)[:, None]
        rgba = model.geom_rgba.copy()
        has_mat = model.geom_matid >= 0
        rgba[has_mat] = model.mat_rgba[model.geom_matid[has_mat]]
        # Colour of each geom in 0..255, and the background as one more entry (index ngeom).
        self._palette = (np.vstack([rgba[:, :3], _BACKGROUND]) * 255.0).astype(np.float32)
        self._light = (_LIGHT_DIR / np.linalg.norm(_LIGHT_DIR)).astype(np.float32)

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

    def _shade(self, z: np.ndarray, hit: np.ndarray, geom_ids: np.ndarray) -> np.ndarray:
        """Lambert shading with normals from the depth image, in float32.

        A pixel's point is P = z (x_u, y_v, 1), so dP/du x dP/dv is parallel to
        n = (-fx z_u, -fy z_v, z + fx x_u z_u + fy y_v z_v) (divided by z / (fx fy) > 0): only the two
        image gradients of z are needed, not the six of the 3-D points.
        """
        z = z.astype(np.float32, copy=False)
        z_v, z_u = np.gradient(z)
        nx = z_u * np.float32(-self.fx)
        ny = z_v * np.float32(-self.fy)
        nz = z + (self._x * np.float32(self.fx)) * z_u + (self._y * np.float32(self.fy)) * z_v
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        lx, ly, lz = (float(c) for c in self._light)
        cos = -(nx * lx + ny * ly + nz * lz)
        lambert = np.divide(cos, norm, out=np.zeros_like(cos), where=norm > 1e-12)
        np.clip(lambert, 0.0, 1.0, out=lambert)
        shade = np.where(hit, np.float32(0.45) + np.float32(0.55) * lambert, np.float32(1.0))
        colour = self._palette[np.where(hit, geom_ids, len(self._palette) - 1)]
        colour *= shade[..., None]
        return colour.astype(np.uint8)
