"""Point clouds: numpy pipeline maths, and ray-cast depth vs a real OpenGL (OSMesa) depth render."""

import ctypes.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lerobot_focal.geometry.pointcloud import (
    DepthCrop,
    PinholeIntrinsics,
    WorkspaceBounds,
    backproject_depth,
    crop_to_workspace,
    farthest_point_sample,
    look_at_pose,
    voxel_downsample,
)

REPO = Path(__file__).resolve().parents[2]


def _fps_reference(points, k, start=0):
    chosen = [start]
    dist = np.linalg.norm(points - points[start], axis=1)
    for _ in range(k - 1):
        nxt = int(dist.argmax())
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(points - points[nxt], axis=1))
    return points[chosen]


def test_farthest_point_sample_matches_reference():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (3000, 3)).astype(np.float32)
    np.testing.assert_array_equal(farthest_point_sample(pts, 256), _fps_reference(pts.astype(np.float64), 256))
    # fewer points than asked: cycled, never zero-padded
    few = farthest_point_sample(pts[:5], 12)
    assert few.shape == (12, 3) and len(np.unique(few, axis=0)) == 5
    assert farthest_point_sample(np.zeros((0, 3)), 4).shape == (4, 3)


def _covering_radius(points: np.ndarray, samples: np.ndarray) -> float:
    """The largest distance from any point to its nearest sample (how well the samples cover the cloud)."""
    from scipy.spatial import cKDTree

    return float(cKDTree(samples).query(points)[0].max())


def test_bucket_fps_on_large_clouds_covers_as_well_as_exact_fps():
    """Large frames use fpsample's bucket FPS: not the same points as the exact loop, but the same coverage;
    and the same input gives the same cloud."""
    pytest.importorskip("fpsample")
    rng = np.random.default_rng(2)
    # A table-top-like frame: a dense plane plus a few objects, 60 k points.
    plane = np.c_[rng.uniform(-0.5, 0.5, (50_000, 2)), rng.normal(0, 0.002, 50_000)]
    boxes = np.concatenate([rng.uniform(np.array(c) - 0.05, np.array(c) + 0.05, (3_000, 3)) for c in ([0.1, 0.2, 0.05],
                            [-0.2, -0.1, 0.08], [0.3, -0.3, 0.1], [0.0, 0.0, 0.2])])
    pts = np.concatenate([plane, boxes]).astype(np.float32)
    fast = farthest_point_sample(pts, 512)
    exact = farthest_point_sample(pts, 512, exact=True)
    assert fast.shape == (512, 3) and len(np.unique(fast, axis=0)) == 512
    assert not np.array_equal(fast, exact)  # the bucket path really ran
    assert _covering_radius(pts, fast) <= 1.15 * _covering_radius(pts, exact)
    np.testing.assert_array_equal(fast, farthest_point_sample(pts, 512))  # deterministic


def test_backprojection_inverts_projection():
    intr = PinholeIntrinsics.from_fovy(45.0, 64, 48)
    pose = look_at_pose(eye=(1.0, -1.0, 1.5), target=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(1)
    world = rng.uniform(-0.3, 0.3, (200, 3))
    cam = (world - pose[:3, 3]) @ pose[:3, :3]  # world -> OpenCV camera frame
    u = np.round(intr.fx * cam[:, 0] / cam[:, 2] + intr.cx).astype(int)
    v = np.round(intr.fy * cam[:, 1] / cam[:, 2] + intr.cy).astype(int)
    inside = (u >= 0) & (u < 64) & (v >= 0) & (v < 48)
    depth = np.zeros((48, 64))
    depth[v[inside], u[inside]] = cam[inside, 2]
    back = backproject_depth(depth, intr, pose)
    # each back-projected pixel lies on the viewing ray of a world point, within the pixel quantisation
    assert len(back) > 100
    for p in back[:20]:
        rays = world - pose[:3, 3]
        cos = (rays @ (p - pose[:3, 3])) / (np.linalg.norm(rays, axis=1) * np.linalg.norm(p - pose[:3, 3]))
        assert cos.max() > 0.9999


def test_crop_and_voxel():
    pts = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.5, 0.5, 0.5], [2.0, 0.0, 0.0]])
    box = WorkspaceBounds((-1, -1, -1), (1, 1, 1))
    assert len(crop_to_workspace(pts, box)) == 3
    np.testing.assert_array_equal(voxel_downsample(pts, 0.01), pts[[0, 2, 3]])


def _scene_depth(intr: PinholeIntrinsics, pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A table-top depth frame in mm (uint16): the z = 0 plane plus boxes, holes (0) and far returns."""
    rays = intr.pixel_rays() @ pose[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -pose[2, 3] / rays[:, 2]  # hits on the z = 0 table plane, z_cam = t
    t = np.where(t > 0, t, 6.0)
    t = t - rng.uniform(0, 0.3, t.size) * (rng.uniform(size=t.size) < 0.2)  # "objects" above the table
    mm = np.clip(np.round(t * 1000.0), 0, 65535).astype(np.uint16)
    mm[rng.uniform(size=mm.size) < 0.05] = 0  # no return
    return mm.reshape(intr.height, intr.width)


@pytest.mark.parametrize(
    ("eye", "low", "high"),
    [
        ((-1.45, -0.15, 0.8), (-1.1, -0.7, 0.003), (-0.2, 0.4, 0.8)),  # the ur10e twin's camera and crop box
        ((0.0, 0.0, 0.5), (-0.5, -0.5, 0.0), (0.5, 0.5, 1.0)),  # camera inside the box, looking straight down
    ],
)
def test_depth_crop_gives_the_points_of_backprojection_then_crop(eye, low, high):
    """The depth-space crop (intervals precomputed per pixel) returns exactly the points of back-projecting
    every pixel and cropping, in the same order, including depth units, min_depth and max_depth."""
    intr = PinholeIntrinsics.from_fovy(58.0, 848, 480)
    pose = look_at_pose(eye=eye, target=(eye[0] + 1e-3 + 0.7 * (eye[2] > 0.6), eye[1], 0.0))
    box = WorkspaceBounds(low, high)
    depth = _scene_depth(intr, pose, np.random.default_rng(3))
    for max_depth, min_depth in ((np.inf, 0.0), (1.2, 0.3)):
        crop = DepthCrop(intr, pose, box, max_depth=max_depth)
        reference = crop_to_workspace(
            backproject_depth(depth, intr, pose, depth_scale=0.001, max_depth=max_depth, min_depth=min_depth), box
        )
        fast = crop(depth, depth_scale=0.001, min_depth=min_depth)
        assert len(reference) > 1000
        np.testing.assert_allclose(fast, reference, rtol=0, atol=1e-12)
        assert crop.num_candidate_pixels <= intr.width * intr.height
    with pytest.raises(ValueError, match="does not match the intrinsics"):
        crop(depth[:-1])
    # The shared cache takes boxes given as arrays too, and reuses the crop of an equal box.
    from lerobot_focal.geometry.pointcloud import cached_depth_crop

    as_arrays = WorkspaceBounds(np.asarray(low, float), np.asarray(high, float))
    assert cached_depth_crop(intr, pose, as_arrays) is cached_depth_crop(intr, pose, WorkspaceBounds(low, high))


@pytest.mark.subprocess
def test_raycast_matches_osmesa_render():
    """Same state, same camera: ray-cast depth vs OSMesa's z-buffer, and the clouds made from each.

    Tolerances: >= 99.5 % of pixels agree on hit/no-hit; <= 1 % of pixels differ by more than 1 mm (silhouette
    pixels, where rasterisation and a ray through the pixel centre may see different surfaces); 99 % of the
    ray-cast surface off the silhouettes within 2 mm of the OpenGL surface; >= 93 % of the 512 cloud points
    within 5 mm of it (the rest are grazing hits on the arm's silhouettes, isolated points that farthest-point
    sampling picks first: ~5 % of a cloud once the table is cropped away); the two 512-point FPS clouds within
    2 cm mean nearest-neighbour distance (FPS spacing is ~4-5 cm).
    """
    pytest.importorskip("gymnasium_robotics")
    # The README's set-up (scripts/setup.sh → scripts/system_libs.sh) installs OSMesa, so its absence is a
    # failure, not a reason to skip; only an explicit opt-out of the system libraries skips.
    if not ctypes.util.find_library("OSMesa"):
        if os.environ.get("LEROBOT_FOCAL_SKIP_SYSTEM_LIBS") == "1":
            pytest.skip("OSMesa missing and LEROBOT_FOCAL_SKIP_SYSTEM_LIBS=1")
        pytest.fail("libOSMesa is not installed: run ./scripts/setup.sh (it installs libosmesa6) "
                    "or apt-get install libosmesa6")
    env = {**os.environ, "MUJOCO_GL": "osmesa", "PYOPENGL_PLATFORM": "osmesa", "PYTHONPATH": str(REPO)}
    result = subprocess.run(
        [sys.executable, "-m", "tests.envs._opengl_compare"], cwd=REPO, env=env, capture_output=True, text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    rows = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    assert len(rows) == 4
    for row in rows:
        assert row["hit_agreement"] >= 0.995, row
        assert row["depth_frac_over_1mm"] <= 0.01, row
        assert row["surface_gap_p99"] <= 0.002, row
        assert row["cloud_frac_within_5mm_of_gl"] >= 0.93, row
        assert row["cloud_nn_mean"] <= 0.02, row
        assert row["cloud_unique_points"] == 512, row



def test_raycast_draws_sphere_sites_only_when_asked():
    """With ``site_groups`` the ray caster sees the sites OpenGL draws (enabled group, not transparent) at the
    right depth; without it, as a real depth camera, only matter."""
    import mujoco

    from lerobot_focal.sim.raycast_camera import RENDERED_SITE_GROUPS, RayCastDepthCamera

    xml = """
    <mujoco>
      <worldbody>
        <camera name="top" pos="0 0 2" xyaxes="1 0 0 0 1 0"/>
        <geom name="floor" type="box" size="1 1 0.01"/>
        <site name="marker" type="sphere" size="0.1" pos="0 0 1" rgba="0 1 0 1"/>
        <site name="hidden" type="sphere" size="0.1" pos="0.3 0 1" rgba="0 1 0 0"/>
        <site name="collision_group" type="sphere" size="0.1" pos="-0.3 0 1" group="4"/>
      </worldbody>
    </mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    drawn = RayCastDepthCamera(model, "top", width=65, height=65, site_groups=RENDERED_SITE_GROUPS)
    plain = RayCastDepthCamera(model, "top", width=65, height=65)
    with_sites, without = drawn.render(data), plain.render(data)
    assert with_sites[32, 32] == pytest.approx(2.0 - 1.1, abs=1e-6)  # the marker's near pole
    assert drawn.last_site_ids[32, 32] == mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "marker")
    assert drawn.last_geom_ids[32, 32] == -1
    assert without[32, 32] == pytest.approx(2.0 - 0.01, abs=1e-6)  # the floor
    # the transparent and the group-4 sites are not drawn: only the marker's pixels differ
    differ = np.abs(with_sites - without) > 1e-6
    assert differ.any() and set(np.unique(drawn.last_site_ids[differ])) == {0}
    assert (drawn.last_site_ids >= 0).sum() == differ.sum()
