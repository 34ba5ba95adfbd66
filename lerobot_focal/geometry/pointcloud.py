"""Depth image -> world-frame point cloud, cropped and farthest-point sampled (DP3 recipe).

Pure numpy on purpose: the real robot (RealSense depth + factory intrinsics) uses the same code as the
simulator, so nothing here imports MuJoCo. Conventions, fixed for every caller:

* camera frame is OpenCV's: x right, y down, z forward (along the optical axis);
* ``depth[v, u]`` is the z-distance in metres along the optical axis (what RealSense and a linearised
  OpenGL depth buffer give), not the length of the ray; 0, negative and non-finite values mean "no return";
* ``cam_to_world`` is a 4x4 homogeneous pose that maps OpenCV camera coordinates to the world frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PinholeIntrinsics:
    """Pinhole intrinsics with integer pixel indices at pixel centres (OpenCV / RealSense convention)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @classmethod
    def from_fovy(cls, fovy_deg: float, width: int, height: int) -> PinholeIntrinsics:
        """MuJoCo cameras are given by a vertical field of view and have square pixels."""
        if not 0.0 < fovy_deg < 180.0:
            raise ValueError(f"fovy must be in (0, 180) degrees, got {fovy_deg}")
        f = 0.5 * height / np.tan(np.deg2rad(fovy_deg) / 2.0)
        return cls(fx=f, fy=f, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=width, height=height)

    def pixel_rays(self) -> np.ndarray:
        """(H*W, 3) camera-frame directions with z = 1, row-major, so ``ray * depth`` is the 3-D point."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        rays = np.empty((self.height * self.width, 3), dtype=np.float64)
        rays[:, 0] = ((u - self.cx) / self.fx).ravel()
        rays[:, 1] = ((v - self.cy) / self.fy).ravel()
        rays[:, 2] = 1.0
        return rays


@dataclass(frozen=True)
class WorkspaceBounds:
    """Axis-aligned world-frame box; points outside it (floor, walls, background) are dropped."""

    low: tuple[float, float, float]
    high: tuple[float, float, float]

    def __post_init__(self) -> None:
        if len(self.low) != 3 or len(self.high) != 3:
            raise ValueError(f"bounds need 3 values each, got low={self.low}, high={self.high}")
        if any(lo >= hi for lo, hi in zip(self.low, self.high, strict=True)):
            raise ValueError(f"every low bound must be below its high bound, got low={self.low}, high={self.high}")

    def contains(self, points: np.ndarray) -> np.ndarray:
        lo = np.asarray(self.low, dtype=points.dtype)
        hi = np.asarray(self.high, dtype=points.dtype)
        return np.all((points > lo) & (points < hi), axis=-1)


def _check_pose(cam_to_world: np.ndarray) -> np.ndarray:
    pose = np.asarray(cam_to_world, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"cam_to_world must be a 4x4 homogeneous matrix, got shape {pose.shape}")
    return pose


def backproject_depth(
    depth: np.ndarray,
    intrinsics: PinholeIntrinsics,
    cam_to_world: np.ndarray | None = None,
    depth_scale: float = 1.0,
    max_depth: float = np.inf,
    min_depth: float = 0.0,
) -> np.ndarray:
    """Return the (N, 3) float64 points of all valid pixels, in the world frame if a pose is given.

    ``depth_scale`` converts raw units to metres (RealSense z16 frames: ``depth_scale=0.001``).
    Pixels at or beyond ``max_depth`` are dropped, like the far plane of a rendered depth buffer, and so are
    those below ``min_depth`` (metres; a sensor's "too close" band).
    """
    depth = np.asarray(depth)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth image shape {depth.shape} does not match the intrinsics "
            f"(height, width) = ({intrinsics.height}, {intrinsics.width})"
        )
    z = depth.reshape(-1).astype(np.float64) * depth_scale
    valid = np.isfinite(z) & (z > 0) & (z >= min_depth) & (z < max_depth)
    idx = np.flatnonzero(valid)
    z = z[idx]
    u = (idx % intrinsics.width).astype(np.float64)
    v = (idx // intrinsics.width).astype(np.float64)
    points = np.empty((idx.size, 3), dtype=np.float64)
    points[:, 0] = (u - intrinsics.cx) / intrinsics.fx * z
    points[:, 1] = (v - intrinsics.cy) / intrinsics.fy * z
    points[:, 2] = z
    if cam_to_world is None:
        return points
    pose = _check_pose(cam_to_world)
    return points @ pose[:3, :3].T + pose[:3, 3]


def crop_to_workspace(points: np.ndarray, bounds: WorkspaceBounds | None) -> np.ndarray:
    """Keep the points strictly inside ``bounds`` (all of them if no bounds are given)."""
    if bounds is None:
        return points
    return points[bounds.contains(points[:, :3])]


class DepthCrop:
    """Back-projection and workspace crop of one fixed camera, with the crop moved into depth space.

    Why: at 848x480 back-projecting every pixel (~400 k points, float64) and then dropping the ~98 % outside the
    workspace cost ~50-90 ms per frame, more than the whole control period. A pixel's point lies on its ray at
    parameter z (rays scaled to z = 1 in the camera), and the box is convex, so the point is inside the box iff z
    lies in the interval where that ray crosses the box. Those intervals depend only on the intrinsics, the pose
    and the box, so they are computed once; per frame only two comparisons per pixel remain, and only the
    surviving pixels are back-projected. The interval test is widened by ``_MARGIN_M`` and every survivor still
    passes the exact :meth:`WorkspaceBounds.contains`, so the output holds the points of ``crop_to_workspace(
    backproject_depth(...))``: the same pixels in the same (row-major) order, coordinates equal up to float64
    rounding (the final matrix product runs on fewer rows).
    """

    _MARGIN_M = 1e-4

    def __init__(
        self,
        intrinsics: PinholeIntrinsics,
        cam_to_world: np.ndarray,
        bounds: WorkspaceBounds,
        max_depth: float = np.inf,
    ) -> None:
        self.intrinsics = intrinsics
        self.pose = _check_pose(cam_to_world).copy()
        self.bounds = bounds
        self.max_depth = float(max_depth)
        rays = intrinsics.pixel_rays() @ self.pose[:3, :3].T  # world-frame directions, z_cam = 1
        origin = self.pose[:3, 3]
        lo = np.asarray(bounds.low, dtype=np.float64) - origin
        hi = np.asarray(bounds.high, dtype=np.float64) - origin
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / rays
            t1, t2 = lo * inv, hi * inv
        # A zero direction component gives nan (origin on a slab face) or +-inf: nan counts as "no limit".
        on_face = np.isnan(t1) | np.isnan(t2)
        near = np.where(on_face, -np.inf, np.minimum(t1, t2)).max(axis=1)
        far = np.where(on_face, np.inf, np.maximum(t1, t2)).min(axis=1)
        near = np.maximum(near, 0.0)
        far = np.minimum(far, self.max_depth)
        crosses = far > near
        self._pixels = np.flatnonzero(crosses)
        self._z_low = (near[crosses] - self._MARGIN_M).astype(np.float32)
        self._z_high = (far[crosses] + self._MARGIN_M).astype(np.float32)

    @property
    def num_candidate_pixels(self) -> int:
        """Pixels whose ray crosses the box at all (the rest are never read)."""
        return int(self._pixels.size)

    def matches(self, intrinsics: PinholeIntrinsics, cam_to_world: np.ndarray, bounds: WorkspaceBounds,
                max_depth: float) -> bool:
        return (
            intrinsics == self.intrinsics
            and np.array_equal(np.asarray(bounds.low, float), np.asarray(self.bounds.low, float))
            and np.array_equal(np.asarray(bounds.high, float), np.asarray(self.bounds.high, float))
            and float(max_depth) == self.max_depth
            and np.array_equal(np.asarray(cam_to_world, dtype=np.float64), self.pose)
        )

    def __call__(self, depth: np.ndarray, depth_scale: float = 1.0, min_depth: float = 0.0) -> np.ndarray:
        """(N, 3) float64 world points of ``depth`` strictly inside the box; depths below ``min_depth`` (metres)
        count as no return."""
        depth = np.asarray(depth)
        intr = self.intrinsics
        if depth.shape != (intr.height, intr.width):
            raise ValueError(
                f"depth image shape {depth.shape} does not match the intrinsics "
                f"(height, width) = ({intr.height}, {intr.width})"
            )
        flat = depth.reshape(-1)
        z32 = flat[self._pixels].astype(np.float32)
        z32 *= np.float32(depth_scale)
        inside = (z32 > self._z_low) & (z32 < self._z_high)
        idx = self._pixels[inside]
        # The survivors are converted exactly as backproject_depth converts them (float64).
        z = flat[idx].astype(np.float64) * depth_scale
        valid = np.isfinite(z) & (z > 0) & (z >= min_depth) & (z < self.max_depth)
        idx, z = idx[valid], z[valid]
        points = np.empty((idx.size, 3), dtype=np.float64)
        points[:, 0] = ((idx % intr.width).astype(np.float64) - intr.cx) / intr.fx * z
        points[:, 1] = ((idx // intr.width).astype(np.float64) - intr.cy) / intr.fy * z
        points[:, 2] = z
        points = points @ self.pose[:3, :3].T + self.pose[:3, 3]
        return points[self.bounds.contains(points)]


_DEPTH_CROPS: list[DepthCrop] = []
_DEPTH_CROP_CACHE_SIZE = 8


def cached_depth_crop(
    intrinsics: PinholeIntrinsics, cam_to_world: np.ndarray, bounds: WorkspaceBounds, max_depth: float = np.inf
) -> DepthCrop:
    """The :class:`DepthCrop` of this camera and box, built once: fixed cameras (every simulated benchmark
    camera, a calibrated robot camera) hit the cache on every frame; a moving camera just rebuilds it."""
    for i, crop in enumerate(_DEPTH_CROPS):
        if crop.matches(intrinsics, cam_to_world, bounds, max_depth):
            _DEPTH_CROPS.insert(0, _DEPTH_CROPS.pop(i))  # least recently used goes first when full
            return crop
    crop = DepthCrop(intrinsics, cam_to_world, bounds, max_depth)
    _DEPTH_CROPS.insert(0, crop)
    del _DEPTH_CROPS[_DEPTH_CROP_CACHE_SIZE:]
    return crop


#: Above this many candidate points, sampling uses the `fpsample` package's bucket FPS (a kd-tree of buckets,
#: O(n log n)) when it is installed: ~4x faster than the exact loop at 50-150 k points (a 848x480 depth frame),
#: with the same coverage (tests/envs/test_pointcloud.py). Below it the exact loop is as fast and bit-stable.
BUCKET_FPS_MIN_POINTS = 8192


def farthest_point_sample(
    points: np.ndarray, num_points: int, start_index: int = 0, exact: bool | None = None
) -> np.ndarray:
    """Farthest-point sampling to exactly ``num_points`` rows, deterministic for a given input.

    Starts at ``start_index`` (DP3 starts at the first point too, so equal inputs give equal clouds).
    Extra columns (e.g. rgb) ride along; distances use xyz only. With fewer input points than asked, the
    sampled points are repeated cyclically rather than zero-padded as DP3 does: a max-pooling encoder is
    blind to duplicates, while a padded (0, 0, 0) would be a fake surface at the world origin. An empty
    input gives zeros, the only option left. ``exact``: True forces the exact loop, False the bucket FPS,
    None (default) picks by size (``BUCKET_FPS_MIN_POINTS``).
    """
    if num_points <= 0:
        raise ValueError(f"num_points must be positive, got {num_points}")
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] < 3:
        raise ValueError(f"points must have shape (N, >=3), got {points.shape}")
    n = points.shape[0]
    if n == 0:
        return np.zeros((num_points, points.shape[1]), dtype=points.dtype)
    if n <= num_points:
        return points[np.resize(np.arange(n), num_points)]
    if not 0 <= start_index < n:
        raise ValueError(f"start_index {start_index} out of range for {n} points")
    xyz = np.ascontiguousarray(points[:, :3], dtype=np.float32)
    if exact is False or (exact is None and n >= BUCKET_FPS_MIN_POINTS):
        chosen = _bucket_fps(xyz, num_points, start_index)
        if chosen is not None:
            return points[chosen]
    return points[_exact_fps(xyz, num_points, start_index)]


def _bucket_fps(xyz: np.ndarray, num_points: int, start_index: int) -> np.ndarray | None:
    try:
        import fpsample
    except ImportError:  # optional (the sim / robot extras install it): fall back to the exact loop
        return None
    height = 5 if xyz.shape[0] < 50_000 else 7  # fpsample's advice: taller bucket trees for larger clouds
    return np.asarray(fpsample.bucket_fps_kdline_sampling(xyz, num_points, h=height, start_idx=start_index))


def _exact_fps(xyz: np.ndarray, num_points: int, start_index: int) -> np.ndarray:
    # Squared distances as |p|^2 - 2 p.c + |c|^2: per iteration one BLAS mat-vec plus three in-place
    # element-wise calls. Python call overhead, not arithmetic, bounds pure-numpy FPS, so the fewer calls per
    # iteration the better. float32 cancellation costs ~1e-7 m^2 here (coordinates ~1 m): far below the
    # spacing of 512 samples, and the selection stays deterministic.
    n = xyz.shape[0]
    sq_norm = np.einsum("ij,ij->i", xyz, xyz)
    d2 = np.empty(n, dtype=np.float32)
    min_d2 = np.full(n, np.inf, dtype=np.float32)
    chosen = np.empty(num_points, dtype=np.int64)
    current = start_index
    for i in range(num_points):
        chosen[i] = current
        np.dot(xyz, xyz[current] * np.float32(-2.0), out=d2)
        d2 += sq_norm + sq_norm[current]
        np.minimum(min_d2, d2, out=min_d2)
        current = int(min_d2.argmax())
    return chosen


def voxel_downsample(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """Keep the first point (in input order, so deterministic) of every occupied voxel.

    Used before FPS to cut its input: FPS cost grows with the candidate count, while 512 FPS points over a
    table top are ~5 cm apart, so 1-2 cm voxels change the sampled cloud by less than a voxel.
    """
    if voxel_size <= 0 or points.shape[0] == 0:
        return points
    keys = np.floor(points[:, :3] / voxel_size).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    flat = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    _, first = np.unique(flat, return_index=True)
    return points[np.sort(first)]


@dataclass(frozen=True)
class PointCloudSpec:
    """Everything that turns one depth frame into the policy's fixed-size cloud."""

    num_points: int = 512
    bounds: WorkspaceBounds | None = None
    max_depth: float = np.inf
    # 0 = exact DP3 recipe (FPS over every cropped point); > 0 voxel-downsamples first (speed, see above).
    voxel_size: float = 0.0


def depth_to_pointcloud(
    depth: np.ndarray,
    intrinsics: PinholeIntrinsics,
    cam_to_world: np.ndarray,
    spec: PointCloudSpec,
    depth_scale: float = 1.0,
    min_depth: float = 0.0,
) -> np.ndarray:
    """Depth frame -> world points -> workspace crop -> (voxel grid) -> FPS; float32 (num_points, 3).

    With bounds, back-projection and crop go through the camera's cached :class:`DepthCrop` (same points,
    ~20x faster at 848x480)."""
    if spec.bounds is not None:
        crop = cached_depth_crop(intrinsics, cam_to_world, spec.bounds, spec.max_depth)
        points = crop(depth, depth_scale, min_depth=min_depth)
    else:
        points = backproject_depth(
            depth, intrinsics, cam_to_world, depth_scale=depth_scale, max_depth=spec.max_depth, min_depth=min_depth
        )
    points = voxel_downsample(points, spec.voxel_size)
    return farthest_point_sample(points, spec.num_points).astype(np.float32, copy=False)


def look_at_pose(eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV cam_to_world pose of a camera at ``eye`` looking at ``target``: handy for extrinsic calibration."""
    eye_v = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye_v
    norm = np.linalg.norm(forward)
    if norm == 0:
        raise ValueError("eye and target coincide")
    forward /= norm
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("up is parallel to the viewing direction")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, down, forward, eye_v
    return pose
