"""Point-cloud observations per second, end to end (ray cast + back-project + crop + voxel + FPS).

    python -m lerobot_focal.benchmarks.pointcloud_rate [--task pick-place-v3] [--frames 30] [--runs 5]

Frames are taken at distinct states of a random-action rollout (the arm moves, so every frame is new work);
the env's own physics step is excluded. Prints the median over runs, for each setting measured, and the same
pipeline with the workspace crop done the old way (back-project every pixel, then crop) for comparison.
"""

from __future__ import annotations

import os
import time

import mujoco
import numpy as np

from lerobot_focal.console import doc_parser
from lerobot_focal.envs.metaworld_env import FocalMetaworldEnv
from lerobot_focal.geometry.pointcloud import (
    PointCloudSpec,
    backproject_depth,
    crop_to_workspace,
    farthest_point_sample,
    voxel_downsample,
)
from lerobot_focal.sim.raycast_camera import RayCastPointCloudSensor


def _record_states(env: FocalMetaworldEnv, frames: int, seed: int) -> list[np.ndarray]:
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    model, data = env._env.model, env._env.data
    states = []
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    for _ in range(frames):
        env._env.step(rng.uniform(-1, 1, 4).astype(np.float32))
        state = np.empty(size)
        mujoco.mj_getState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        states.append(state)
    return states


def _cloud_cropped_after_backprojection(depth: np.ndarray, intrinsics, cam_to_world: np.ndarray,
                                        spec: PointCloudSpec, depth_scale: float = 1.0) -> np.ndarray:
    """The pipeline as it was before `DepthCrop`: every pixel back-projected, then cropped, voxels, FPS."""
    points = backproject_depth(depth, intrinsics, cam_to_world, depth_scale=depth_scale, max_depth=spec.max_depth)
    points = voxel_downsample(crop_to_workspace(points, spec.bounds), spec.voxel_size)
    return farthest_point_sample(points, spec.num_points).astype(np.float32)


def _crop_after_backprojection(sensor: RayCastPointCloudSensor, data: mujoco.MjData) -> np.ndarray:
    camera = sensor.camera
    return _cloud_cropped_after_backprojection(camera.render(data), camera.intrinsics, camera.pose(data).matrix(),
                                               sensor.spec)


def measure(
    task: str, frames: int, runs: int, threads: int, voxel_size: float, seed: int = 0, crop_first: bool = False
) -> tuple[float, float, int]:
    """Median observations/s (wall clock) and CPU ms per observation over ``runs`` passes of ``frames``
    distinct states; also the mean number of rays mj_multiRay cast per frame."""
    env = FocalMetaworldEnv(task=task, obs_type="pointcloud")  # its crop box: the table cropped per task
    env._ensure_env()
    spec = PointCloudSpec(num_points=512, bounds=env.pointcloud_spec.bounds, voxel_size=voxel_size)
    sensor = RayCastPointCloudSensor(env._env.model, env.camera_name, spec, 128, 128, num_threads=threads)
    states = _record_states(env, frames, seed)
    model, data = env._env.model, env._env.data
    rates, cpu_ms, cast = [], [], []
    for _ in range(runs):
        elapsed = cpu = 0.0
        for state in states:
            mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
            mujoco.mj_forward(model, data)
            start, start_cpu = time.perf_counter(), time.process_time()
            cloud = _crop_after_backprojection(sensor, data) if crop_first else sensor(data)
            elapsed += time.perf_counter() - start
            cpu += time.process_time() - start_cpu
            cast.append(sensor.camera.num_cast_rays)
            assert cloud.shape == (512, 3)
        rates.append(len(states) / elapsed)
        cpu_ms.append(1e3 * cpu / len(states))
    sensor.close()
    env.close()
    return float(np.median(rates)), float(np.median(cpu_ms)), int(np.mean(cast))


def measure_robot_frame(width: int = 848, height: int = 480, repeats: int = 15) -> tuple[float, float, int]:
    """Median ms to turn one UR-10e twin depth frame (the D435i's resolution) into 512 points, with the
    depth-space crop and with every pixel back-projected first (same run), and the cropped point count."""
    from pathlib import Path
    from tempfile import TemporaryDirectory

    from lerobot_focal.geometry.pointcloud import (
        PinholeIntrinsics,
        WorkspaceBounds,
        cached_depth_crop,
        depth_to_pointcloud,
    )
    from lerobot_focal.robots.ur10e import UR10e, UR10eConfig
    from lerobot_focal.robots.ur10e.twin.scene import TABLE_TOP_BOX

    with TemporaryDirectory() as tmp:
        robot = UR10e(UR10eConfig(backend="sim", sim_camera_width=width, sim_camera_height=height,
                                  calibration_dir=Path(tmp)))
        robot.connect()
        try:
            depth = robot.get_observation()["front_depth"][..., 0]
            info = robot.camera_infos()["front"]
        finally:
            robot.disconnect()
    intr = PinholeIntrinsics(fx=info.fx, fy=info.fy, cx=info.cx, cy=info.cy, width=info.width, height=info.height)
    pose = np.asarray(info.T_base_cam)
    spec = PointCloudSpec(num_points=512, bounds=WorkspaceBounds(*TABLE_TOP_BOX))

    def old() -> np.ndarray:
        return _cloud_cropped_after_backprojection(depth, intr, pose, spec, depth_scale=0.001)

    def new() -> np.ndarray:
        return depth_to_pointcloud(depth, intr, pose, spec, depth_scale=0.001)

    times: dict[str, list[float]] = {"new": [], "old": []}
    for _ in range(repeats):  # interleaved, so both see the same machine load
        for name, fn in (("new", new), ("old", old)):
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    np.testing.assert_allclose(new(), old(), rtol=0, atol=1e-6)  # same cloud (float64 rounding aside)
    cropped = len(cached_depth_crop(intr, pose, spec.bounds)(depth, depth_scale=0.001))
    return 1e3 * float(np.median(times["new"])), 1e3 * float(np.median(times["old"])), cropped


def main(argv: list[str] | None = None) -> None:
    parser = doc_parser(__doc__, "python -m lerobot_focal.benchmarks.pointcloud_rate")
    parser.add_argument("--task", default="pick-place-v3")
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args(argv)
    load = os.getloadavg()[0]
    print(f"MetaWorld {args.task}, camera corner2, 128x128 rays -> 512 points; {os.cpu_count()} cores, load {load:.2f}")
    for threads, voxel, crop_first in ((1, 0.01, False), (1, 0.01, True), (1, 0.0, False), (2, 0.01, False)):
        rate, cpu_ms, rays = measure(args.task, args.frames, args.runs, threads, voxel, crop_first=crop_first)
        label = "exact FPS" if voxel == 0 else f"voxel {voxel * 100:.0f} cm + FPS"
        label += ", crop after back-projecting all pixels" if crop_first else ""
        print(
            f"threads={threads} {label:<58} rays cast/frame={rays:5d}  {rate:6.1f} obs/s  "
            f"({1e3 / rate:5.1f} ms/obs wall, {cpu_ms:5.1f} ms CPU)"
        )
    new_ms, old_ms, cropped = measure_robot_frame()
    print(f"UR-10e twin, one 848x480 depth frame -> 512 points ({cropped} points in the crop box): "
          f"{new_ms:.1f} ms with the depth-space crop, {old_ms:.1f} ms back-projecting every pixel first "
          f"({old_ms / new_ms:.1f}x; same cloud)")


if __name__ == "__main__":
    main()
