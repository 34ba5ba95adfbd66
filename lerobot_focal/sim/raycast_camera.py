"""A MuJoCo depth camera made of rays (``mujoco.mj_multiRay``): depth images with no OpenGL at all.

Why: it needs no OpenGL at all (no GPU, no EGL device, no OSMesa library), so point-cloud envs run on any
machine and inside any worker process. Casting one ray per pixel gives the same z-depth as the rasteriser
(tests/envs/test_pointcloud.py compares it with an OSMesa render: >= 99 % of pixels within 1 mm) and, with
the tricks below, a whole 512-point cloud in about 28 ms on one core of a 2-core CPU:

* ray directions are precomputed once per camera pose, scaled so that z = 1 in the camera frame; MuJoCo
  returns hit distances in units of the direction vector, so the result *is* the z-depth (no division);
* only geom groups 0-2 are cast against, the groups MuJoCo renders by default, so collision-only geoms
  (groups 3-5) are neither paid for nor mistaken for surfaces;
* sites are markers that ``mj_ray`` ignores; with ``site_groups`` the drawn sphere sites are intersected
  analytically, as an OpenGL render shows them (the sim envs do, so that clouds match DP3's rasterised ones);
* with workspace bounds given, pixels whose ray segment cannot enter the box are never cast: whatever such
  a ray hits would be cropped away anyway, so skipping them is exact, not an approximation;
* static geoms (table, walls, fixtures) are ray-cast once per camera pose with exact single-ray ``mj_ray``
  and merged into each frame with ``min``; per frame they are parked out of ``mj_multiRay``'s reach, so it
  only tests the moving geoms (arm, objects). Besides speed this works around ``mj_multiRay``'s angular
  culling, which takes azimuth/elevation bounds from a geom box's 8 corners and so misses rays into the
  middle of large geoms seen from nearby (measured: up to 9 % of a MetaWorld frame wrong without it);
* ``mj_multiRay`` allocates scratch memory on ``mjData``'s stack, so rays are cast against scratch
  ``mjData`` copies holding the poses it reads (``geom_xpos``, ``geom_xmat`` and the body ``xipos`` its
  bounding-sphere test uses), never the simulation's ``mjData``. Optional worker threads split the rays
  (mj_multiRay releases the GIL); the default is one thread, the fastest when the other cores are busy.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import mujoco
import numpy as np

from lerobot_focal.geometry.pointcloud import PinholeIntrinsics, PointCloudSpec, WorkspaceBounds, depth_to_pointcloud

#: MuJoCo's default ``mjvOption.geomgroup``: what an OpenGL render of the scene shows.
RENDERED_GEOM_GROUPS: tuple[int, ...] = (1, 1, 1, 0, 0, 0)
#: MuJoCo's default ``mjvOption.sitegroup``: the sites an OpenGL render draws.
RENDERED_SITE_GROUPS: tuple[int, ...] = (1, 1, 1, 0, 0, 0)
# Where static geoms are moved in the per-frame scratch data: beyond any cutoff, so mj_multiRay skips them.
_PARKED = 1e9
# Corners of the cube [-1, 1]^3, scaled by a bounding-sphere radius to bound a geom.
_CUBE_CORNERS = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
# OpenCV camera axes expressed in MuJoCo's camera frame (x right, y up, looking down -z).
_CV_FROM_MJ = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class CameraPose:
    """Camera centre and OpenCV-convention rotation (columns = camera x, y, z axes in world)."""

    position: np.ndarray
    rotation: np.ndarray

    def matrix(self) -> np.ndarray:
        pose = np.eye(4)
        pose[:3, :3] = self.rotation
        pose[:3, 3] = self.position
        return pose


def mujoco_camera_pose(model: mujoco.MjModel, data: mujoco.MjData, camera_id: int) -> CameraPose:
    """Pose of a named MuJoCo camera after ``mj_forward``, converted to the OpenCV convention."""
    rotation = data.cam_xmat[camera_id].reshape(3, 3) @ _CV_FROM_MJ
    return CameraPose(position=data.cam_xpos[camera_id].copy(), rotation=rotation)


def drawn_sphere_sites(model: mujoco.MjModel, site_groups: tuple[int, ...]) -> np.ndarray:
    """Ids of the sphere sites OpenGL draws: in an enabled group and not fully transparent.

    Sites are markers, not matter: mj_ray ignores them and a real depth camera never sees them, but a
    rasterised depth image (what DP3's MetaWorld clouds are made from) contains every drawn site, MetaWorld's
    goal marker included. Only spheres are supported (MetaWorld's sites all are); other shapes are left out.
    """
    if len(site_groups) != mujoco.mjNGROUP:
        raise ValueError(f"site_groups needs {mujoco.mjNGROUP} flags, got {len(site_groups)}")
    enabled = np.asarray(site_groups, dtype=bool)[np.clip(model.site_group, 0, mujoco.mjNGROUP - 1)]
    alpha = model.site_rgba[:, 3].copy()
    material = model.site_matid >= 0
    alpha[material] = model.mat_rgba[model.site_matid[material], 3]
    sphere = model.site_type == mujoco.mjtGeom.mjGEOM_SPHERE
    return np.flatnonzero(enabled & (alpha > 0) & sphere)


def _sphere_hits(
    origin: np.ndarray, rays: np.ndarray, centres: np.ndarray, radii: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest entry of each ray ``origin + t * ray`` (t > 0) into any of the spheres: (t, sphere index), with
    (inf, -1) for rays that miss them all. t is in units of the ray vector, so z-depth for camera rays."""
    best = np.full(rays.shape[0], np.inf)
    which = np.full(rays.shape[0], -1, dtype=np.int64)
    a = np.einsum("ij,ij->i", rays, rays)
    for k, (centre, radius) in enumerate(zip(centres, radii, strict=True)):
        oc = origin - centre
        b = rays @ oc
        disc = b * b - a * (oc @ oc - radius * radius)
        with np.errstate(invalid="ignore"):
            t = (-b - np.sqrt(disc)) / a
        t = np.where((disc >= 0) & (t > 0), t, np.inf)
        closer = t < best
        best = np.where(closer, t, best)
        which = np.where(closer, k, which)
    return best, which


def _segment_hits_box(
    origin: np.ndarray, directions: np.ndarray, t_max: float, bounds: WorkspaceBounds
) -> np.ndarray:
    """Slab test: does ``origin + t * dir`` for some t in (0, t_max] pass through the box?"""
    lo = np.asarray(bounds.low, dtype=np.float64) - origin
    hi = np.asarray(bounds.high, dtype=np.float64) - origin
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / directions
        t1 = lo * inv
        t2 = hi * inv
    t_near = np.minimum(t1, t2)
    t_far = np.maximum(t1, t2)
    # A zero direction component gives nan when the origin lies on a slab face: treat it as "inside".
    t_near = np.where(np.isnan(t_near), -np.inf, t_near).max(axis=1)
    t_far = np.where(np.isnan(t_far), np.inf, t_far).min(axis=1)
    return (t_far >= np.maximum(t_near, 0.0)) & (t_near <= t_max)


def _opaque(model: mujoco.MjModel) -> np.ndarray:
    """Per geom: can a ray hit it? ``mj_ray`` skips geoms whose colour (the material's, if any) has alpha 0,
    such as MetaWorld's mocap geom, which moves with the hand every step."""
    alpha = model.geom_rgba[:, 3].copy()
    has_material = model.geom_matid >= 0
    alpha[has_material] = model.mat_rgba[model.geom_matid[has_material], 3]
    return alpha > 0


class RayCastDepthCamera:
    """Renders z-depth images of a MuJoCo scene from a named camera by casting one ray per pixel.

    ``render`` returns float32 (height, width) metres; 0 marks "no return": the ray hit nothing within
    ``max_depth``, or was skipped because it cannot reach ``skip_outside`` (the workspace box).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        camera: str,
        width: int = 128,
        height: int = 128,
        max_depth: float = 10.0,
        skip_outside: WorkspaceBounds | None = None,
        geom_groups: tuple[int, ...] = RENDERED_GEOM_GROUPS,
        num_threads: int | None = None,
        site_groups: tuple[int, ...] | None = None,
    ) -> None:
        camera_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if camera_id < 0:
            names = [model.camera(i).name for i in range(model.ncam)]
            raise ValueError(f"camera {camera!r} not in the model; available cameras: {names}")
        if len(geom_groups) != mujoco.mjNGROUP:
            raise ValueError(f"geom_groups needs {mujoco.mjNGROUP} flags, got {len(geom_groups)}")
        self.model = model
        self.camera_id = camera_id
        self.intrinsics = PinholeIntrinsics.from_fovy(float(model.cam_fovy[camera_id]), width, height)
        self.max_depth = float(max_depth)
        self.skip_outside = skip_outside
        self._geomgroup = np.asarray(geom_groups, dtype=np.uint8)
        self._cam_rays = self.intrinsics.pixel_rays()  # (H*W, 3), z = 1, OpenCV camera frame
        # The farthest a z-depth of max_depth can be along an unnormalised ray: bounds mj_multiRay's cutoff.
        self._cutoff = self.max_depth * float(np.linalg.norm(self._cam_rays, axis=1).max())
        self._num_threads = max(1, num_threads if num_threads is not None else 1)
        self._pool: ThreadPoolExecutor | None = None
        self._scratch = [mujoco.MjData(model) for _ in range(self._num_threads)]
        # Static geoms (welded to the world) are ray-cast once per camera pose (see _static_depth); per frame
        # they are parked far away in the scratch data, where mj_multiRay's cutoff test drops them for free.
        self._static_geoms = model.body_weldid[model.geom_bodyid] == 0
        visible = self._geomgroup[np.clip(model.geom_group, 0, mujoco.mjNGROUP - 1)] > 0
        self._dynamic_geoms = np.flatnonzero(~self._static_geoms & visible)
        # "Static" means welded to the world, not fixed for good: tasks move such bodies between episodes through
        # the model (MetaWorld's basketball hoop and disassemble peg, Adroit's door frame). The static depth is
        # cached per pose of the static geoms a ray can hit, so a reset that moves one recomputes it.
        self._static_hittable = np.flatnonzero(self._static_geoms & visible & _opaque(model))
        self._last_cast = 0
        self._pose_key: np.ndarray | None = None
        self._active: np.ndarray = np.arange(0)
        self._active_mask: np.ndarray = np.zeros(0, dtype=bool)
        self._world_rays: np.ndarray = np.zeros((0, 3))
        self._static_full: np.ndarray = np.zeros(0)
        self._static_gid: np.ndarray = np.zeros(0, dtype=np.int32)
        #: Geom id seen by each pixel of the last frame (-1: nothing within max_depth, or a site); for colour
        #: shading.
        self.last_geom_ids: np.ndarray = np.zeros((0, 0), dtype=np.int32)
        #: Site id seen by each pixel of the last frame (-1: none), when sites are drawn (``site_groups``).
        self.last_site_ids: np.ndarray = np.zeros((0, 0), dtype=np.int32)
        self._sites = drawn_sphere_sites(model, site_groups) if site_groups is not None else np.arange(0)

    @property
    def width(self) -> int:
        return self.intrinsics.width

    @property
    def height(self) -> int:
        return self.intrinsics.height

    def pose(self, data: mujoco.MjData) -> CameraPose:
        return mujoco_camera_pose(self.model, data, self.camera_id)

    def _prepare(self, pose: CameraPose, data: mujoco.MjData) -> None:
        """Per camera pose and pose of the static geoms (once per episode at most for a fixed camera): world
        rays, the workspace mask, the static depth."""
        ids = self._static_hittable
        key = np.concatenate(
            [pose.position, pose.rotation.ravel(), data.geom_xpos[ids].ravel(), data.geom_xmat[ids].ravel()]
        )
        if self._pose_key is not None and np.array_equal(key, self._pose_key):
            return
        self._world_rays = np.ascontiguousarray(self._cam_rays @ pose.rotation.T)
        if self.skip_outside is None:
            self._active_mask = np.ones(self._world_rays.shape[0], dtype=bool)
        else:
            self._active_mask = _segment_hits_box(pose.position, self._world_rays, self.max_depth, self.skip_outside)
        self._active = np.flatnonzero(self._active_mask)
        self._static_full = np.full(self._world_rays.shape[0], np.inf)
        self._static_gid = np.full(self._world_rays.shape[0], -1, dtype=np.int32)
        dist, gid = self._static_depth(pose.position, self._world_rays[self._active], data)
        self._static_full[self._active] = dist
        self._static_gid[self._active] = gid
        self._pose_key = key

    def _static_depth(
        self, origin: np.ndarray, world_rays: np.ndarray, data: mujoco.MjData
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per-ray distance to the static geoms alone (inf = none) and the geom hit (-1), with exact ``mj_ray``.

        ``mj_multiRay`` culls geoms by azimuth/elevation bounds taken from the 8 corners of each geom's box;
        for large geoms seen from nearby (a table top below the camera) the interior of the geom reaches
        angles no corner does, and rays that do hit it are culled. Static geoms never move, so their exact
        depth is computed once per camera pose here and merged with ``min`` into every frame.
        """
        model = self.model
        static = self._static_geoms
        out = np.full(world_rays.shape[0], np.inf)
        hit = np.full(world_rays.shape[0], -1, dtype=np.int32)
        if not static.any():
            return out, hit
        scratch = mujoco.MjData(model)
        scratch.geom_xmat[:] = data.geom_xmat
        scratch.geom_xpos[:] = np.where(static[:, None], data.geom_xpos, _PARKED)  # park moving geoms far away
        geomid = np.zeros(1, np.int32)
        for i, vec in enumerate(world_rays):
            dist = mujoco.mj_ray(model, scratch, origin, vec, self._geomgroup, 1, -1, geomid)
            if geomid[0] >= 0 and static[geomid[0]]:
                out[i] = dist
                hit[i] = geomid[0]
        return out, hit

    def _dynamic_pixels(self, pose: CameraPose, data: mujoco.MjData) -> np.ndarray:
        """Flat mask of the pixels whose ray can hit a moving geom: the union, over moving geoms, of the image
        rectangle bounding the projection of the cube around the geom's bounding sphere (conservative: a ray
        that hits a geom passes through its bounding sphere)."""
        ids = self._dynamic_geoms
        mask = np.zeros((self.height, self.width), dtype=bool)
        if ids.size == 0:
            return mask.ravel()
        centre = (data.geom_xpos[ids] - pose.position) @ pose.rotation  # OpenCV camera frame
        radius = self.model.geom_rbound[ids]
        corners = centre[:, None, :] + radius[:, None, None] * _CUBE_CORNERS[None]  # (G, 8, 3)
        z = corners[..., 2]
        in_front = z.min(axis=1) > 1e-6
        behind = z.max(axis=1) <= 0
        intr = self.intrinsics
        if np.any(~in_front & ~behind):  # a bounding cube straddles the camera plane: cast everything
            return np.ones(self.height * self.width, dtype=bool)
        keep = in_front
        with np.errstate(divide="ignore", invalid="ignore"):
            u = intr.fx * corners[keep, :, 0] / z[keep] + intr.cx
            v = intr.fy * corners[keep, :, 1] / z[keep] + intr.cy
        u0 = np.clip(np.floor(u.min(axis=1)) - 1, 0, self.width).astype(int)
        u1 = np.clip(np.ceil(u.max(axis=1)) + 2, 0, self.width).astype(int)
        v0 = np.clip(np.floor(v.min(axis=1)) - 1, 0, self.height).astype(int)
        v1 = np.clip(np.ceil(v.max(axis=1)) + 2, 0, self.height).astype(int)
        for a, b, c, d in zip(v0, v1, u0, u1, strict=True):
            mask[a:b, c:d] = True
        return mask.ravel()

    def _cast(self, chunk: np.ndarray, scratch: mujoco.MjData, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        geomid = np.empty(chunk.size, np.int32)
        dist = np.empty(chunk.size, np.float64)
        if chunk.size:
            vec = self._world_rays[chunk].ravel()
            mujoco.mj_multiRay(
                self.model, scratch, origin, vec, self._geomgroup, 1, -1, geomid, dist, chunk.size, self._cutoff
            )
        return geomid, dist

    def render(self, data: mujoco.MjData) -> np.ndarray:
        """Depth image of the current state of ``data`` (which must be up to date, e.g. after mj_forward)."""
        pose = self.pose(data)
        self._prepare(pose, data)
        for scratch in self._scratch:
            scratch.geom_xpos[:] = data.geom_xpos
            scratch.geom_xpos[self._static_geoms] = _PARKED
            scratch.geom_xmat[:] = data.geom_xmat
            # mj_multiRay culls whole bodies by bounding spheres placed at xipos: a scratch mjData left
            # at zeros there silently drops most of the scene.
            scratch.xipos[:] = data.xipos
        origin = pose.position
        # Only pixels that can see a moving geom are cast; the rest keep the static depth.
        cast = np.flatnonzero(self._active_mask & self._dynamic_pixels(pose, data))
        self._last_cast = int(cast.size)
        chunks = np.array_split(cast, self._num_threads)
        if self._num_threads == 1:
            results = [self._cast(chunks[0], self._scratch[0], origin)]
        else:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=self._num_threads, thread_name_prefix="raycast")
            results = list(self._pool.map(self._cast, chunks, self._scratch, [origin] * self._num_threads))
        full = self._static_full.copy()
        gid = self._static_gid.copy()
        for chunk, (geomid, dist) in zip(chunks, results, strict=True):
            closer = (geomid >= 0) & (dist < full[chunk])
            full[chunk] = np.where(closer, dist, full[chunk])
            gid[chunk] = np.where(closer, geomid, gid[chunk])
        sid = np.full(full.shape, -1, dtype=np.int32)
        if self._sites.size:
            active = self._active
            dist, hit = _sphere_hits(origin, self._world_rays[active], data.site_xpos[self._sites],
                                     self.model.site_size[self._sites, 0])
            closer = (hit >= 0) & (dist < full[active])
            full[active] = np.where(closer, dist, full[active])
            sid[active] = np.where(closer, self._sites[np.maximum(hit, 0)], -1)
            gid[active] = np.where(closer, -1, gid[active])
        seen = full <= self.max_depth
        self.last_geom_ids = np.where(seen, gid, -1).reshape(self.height, self.width)
        self.last_site_ids = np.where(seen, sid, -1).reshape(self.height, self.width)
        return np.where(seen, full, 0.0).astype(np.float32).reshape(self.height, self.width)

    @property
    def num_cast_rays(self) -> int:
        """Rays cast by mj_multiRay in the last frame (the rest came from the cached static depth)."""
        return self._last_cast

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __getstate__(self) -> dict:
        # Thread pools cannot be pickled (gymnasium's AsyncVectorEnv may pickle env factories' results).
        state = self.__dict__.copy()
        state["_pool"] = None
        return state


class RayCastPointCloudSensor:
    """Ray-cast depth -> the generic back-projection/crop/FPS of ``pointcloud`` (same path as a real camera)."""

    def __init__(
        self,
        model: mujoco.MjModel,
        camera: str,
        spec: PointCloudSpec,
        width: int = 128,
        height: int = 128,
        max_depth: float = 10.0,
        num_threads: int | None = None,
        site_groups: tuple[int, ...] | None = None,
    ) -> None:
        self.spec = spec
        self.camera = RayCastDepthCamera(
            model, camera, width=width, height=height, max_depth=min(max_depth, spec.max_depth),
            skip_outside=spec.bounds, num_threads=num_threads, site_groups=site_groups,
        )

    def __call__(self, data: mujoco.MjData) -> np.ndarray:
        depth = self.camera.render(data)
        return depth_to_pointcloud(depth, self.camera.intrinsics, self.camera.pose(data).matrix(), self.spec)

    def close(self) -> None:
        self.camera.close()
