"""Run under MUJOCO_GL=osmesa (or egl): ray-cast depth/point cloud vs MuJoCo's OpenGL depth render.

Prints one JSON line per checked state. Used by test_pointcloud.py in a subprocess, because MuJoCo picks its
OpenGL backend once, when it is first imported.
"""

import json
import sys

import mujoco
import numpy as np
from scipy.spatial import cKDTree

from lerobot_focal.envs.focal_adroit import FocalAdroitEnvConfig
from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig
from lerobot_focal.geometry.pointcloud import backproject_depth, crop_to_workspace, depth_to_pointcloud
from lerobot_focal.sim.raycast_camera import RENDERED_SITE_GROUPS, RayCastDepthCamera


def gl_depth(renderer: mujoco.Renderer, model, data, camera: str) -> np.ndarray:
    renderer.update_scene(data, camera=camera)
    depth = renderer.render().astype(np.float32)
    far = model.vis.map.zfar * model.stat.extent
    return np.where(depth < 0.999 * far, depth, 0.0)  # far plane = no return, as the ray caster reports it


def silhouette_pixels(depth: np.ndarray, jump: float = 0.05) -> np.ndarray:
    """Pixels whose depth differs from a 4-neighbour's by more than ``jump`` (m), a miss next to a hit included."""
    edge = np.zeros(depth.shape, bool)
    for axis in (0, 1):
        step = np.abs(np.diff(depth, axis=axis)) > jump
        pad = [(0, 0), (0, 0)]
        pad[axis] = (0, 1)
        edge |= np.pad(step, pad)
        pad[axis] = (1, 0)
        edge |= np.pad(step, pad)
    return edge


def compare(env, steps: int, seed: int) -> dict:
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
    sim = env._env.unwrapped if hasattr(env._env, "unwrapped") else env._env
    model, data = sim.model, sim.data
    sensor = env._pc_sensor
    cam: RayCastDepthCamera = sensor.camera
    # Full frame, no workspace skipping, so every pixel is compared.
    full = RayCastDepthCamera(model, env.camera_name, cam.width, cam.height, skip_outside=None, num_threads=1,
                              site_groups=RENDERED_SITE_GROUPS)  # OpenGL draws sites too
    ray = full.render(data)
    renderer = mujoco.Renderer(model, cam.height, cam.width)
    renderer.enable_depth_rendering()
    gl = gl_depth(renderer, model, data, env.camera_name)
    renderer.close()
    both = (ray > 0) & (gl > 0)
    diff = np.abs(ray - gl)[both]
    cloud_ray = sensor(data)
    cloud_gl = depth_to_pointcloud(gl, cam.intrinsics, cam.pose(data).matrix(), sensor.spec)
    nn = np.concatenate([cKDTree(cloud_gl).query(cloud_ray)[0], cKDTree(cloud_ray).query(cloud_gl)[0]])
    # Every ray-cast point should lie on the surface OpenGL drew: distance to the dense GL points. Silhouette
    # pixels are left out of the surface gap: there rasterisation and a ray through the pixel centre may see
    # different surfaces, and a ray grazing a curved edge lands centimetres along it from where the
    # neighbouring pixel's ray hit. Such grazing hits are isolated points, which farthest-point sampling picks
    # first: with the table cropped away they are ~5 % of an arm-dominated cloud.
    pose = cam.pose(data).matrix()
    gl_surface = crop_to_workspace(backproject_depth(gl, cam.intrinsics, pose), sensor.spec.bounds)
    on_surface = cKDTree(gl_surface).query(cloud_ray)[0]
    interior = np.where(silhouette_pixels(ray), 0.0, ray)
    ray_surface = crop_to_workspace(backproject_depth(interior, cam.intrinsics, pose), sensor.spec.bounds)
    surface_gap = cKDTree(gl_surface).query(ray_surface)[0]
    return {
        "pixels": int(ray.size),
        "hit_agreement": float(((ray > 0) == (gl > 0)).mean()),
        "depth_frac_over_1mm": float((diff > 1e-3).mean()),
        "depth_median_abs": float(np.median(diff)),
        "cloud_nn_mean": float(nn.mean()),
        "cloud_nn_p95": float(np.percentile(nn, 95)),
        "surface_gap_p99": float(np.percentile(surface_gap, 99)),
        "cloud_frac_within_5mm_of_gl": float((on_surface < 5e-3).mean()),
        "cloud_unique_points": int(len(np.unique(cloud_ray, axis=0))),
    }


def main() -> None:
    cases = [
        ("metaworld", "pick-place", 15, 0),
        ("metaworld", "shelf-place", 10, 1),
        ("metaworld", "door-open", 10, 2),
        ("adroit", "door", 5, 0),
    ]
    for suite, task, steps, seed in cases:
        if suite == "metaworld":
            env = FocalMetaworldEnvConfig(task=task, obs_type="pointcloud").make_single_env()
        else:
            env = FocalAdroitEnvConfig(task=task, obs_type="pointcloud").make_single_env()
        result = compare(env, steps, seed)
        env.close()
        print(json.dumps({"suite": suite, "task": task, **result}), flush=True)


if __name__ == "__main__":
    sys.exit(main())
