"""UR-10e driver against its real MuJoCo twin (no mocks): API, motion, safety, gripper, camera geometry."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

pytest.importorskip("mujoco")

from lerobot.robots.utils import make_robot_from_config  # noqa: E402

from lerobot_focal.config_errors import ConfigError  # noqa: E402
from lerobot_focal.robots.ur10e import UnsafeActionError, UR10e, UR10eConfig  # noqa: E402
from lerobot_focal.robots.ur10e.kinematics import HOME_Q, dh_forward  # noqa: E402
from lerobot_focal.robots.ur10e.safety import RobotFaultError, SafetyConfig  # noqa: E402


def _tcp(obs: dict) -> np.ndarray:
    return np.array([obs[f"ee_{a}.pos"] for a in ("x", "y", "z", "roll", "pitch", "yaw")])


@pytest.fixture
def robot(tmp_path):
    cfg = UR10eConfig(backend="sim", calibration_dir=tmp_path, safety=SafetyConfig(watchdog_timeout_s=0.3))
    r = UR10e(cfg)
    r.connect()
    yield r
    if r.is_connected:
        r.disconnect()


def _run(robot: UR10e, action: dict, steps: int) -> dict:
    sent = {}
    for _ in range(steps):
        sent = robot.send_action(action)
        time.sleep(1.0 / robot.config.control_hz)
    return sent


def test_make_robot_from_config_returns_ur10e(tmp_path):
    cfg = UR10eConfig(backend="sim", calibration_dir=tmp_path)
    robot = make_robot_from_config(cfg)
    assert isinstance(robot, UR10e)
    assert cfg.type == "ur10e"
    # Features are known while disconnected.
    assert not robot.is_connected
    assert robot.observation_features["front_depth"] == (128, 128, 1)
    assert list(robot.action_features) == [
        "ee_x.vel", "ee_y.vel", "ee_z.vel", "ee_roll.vel", "ee_pitch.vel", "ee_yaw.vel", "gripper.pos"
    ]  # fmt: skip
    # lerobot-rollout only routes robot features ending in .pos / .vel to and from the policy.
    assert all(k.endswith((".pos", ".vel")) for k in robot.action_features)
    assert all(k.endswith(".pos") for k, ft in robot.observation_features.items() if ft is float)
    abs_robot = UR10e(UR10eConfig(backend="sim", action_mode="absolute", calibration_dir=tmp_path))
    assert list(abs_robot.action_features)[:6] == [f"ee_{a}.pos" for a in ("x", "y", "z", "roll", "pitch", "yaw")]
    assert len(robot.cameras) == 1  # lerobot-record sizes its image writer with len(robot.cameras)


def test_bad_config_is_rejected():
    with pytest.raises(ConfigError, match="backend"):
        UR10eConfig(backend="ros")
    with pytest.raises(ConfigError, match="action_mode"):
        UR10eConfig(action_mode="joint")


def test_model_matches_dh_table(robot):
    obs = robot.get_observation()
    t = dh_forward(np.array(HOME_Q), robot.config.tcp_offset)
    np.testing.assert_allclose(_tcp(obs)[:3], t[:3, 3], atol=2e-3)
    np.testing.assert_allclose(_tcp(obs)[3:], 0.0, atol=1e-2)  # home = tool pointing down, yaw 0


def test_observation_shapes_and_dtypes(robot):
    obs = robot.get_observation()
    assert set(obs) == set(robot.observation_features)
    for key, ft in robot.observation_features.items():
        if ft is float:
            assert isinstance(obs[key], float) and math.isfinite(obs[key]), key
        else:
            assert obs[key].shape == ft, key
    assert obs["front"].dtype == np.uint8
    assert obs["front_depth"].dtype == np.uint16


def test_delta_moves_tcp_toward_target(robot):
    start = _tcp(robot.get_observation())
    sent = _run(robot, {"ee_x.vel": 0.12, "ee_z.vel": -0.12}, 25)  # 4 mm per step at 30 Hz
    time.sleep(0.3)
    end = _tcp(robot.get_observation())
    moved = end[:3] - start[:3]
    assert moved[0] > 0.06 and moved[2] < -0.06, moved
    assert abs(moved[1]) < 0.01
    np.testing.assert_allclose(end[3:], start[3:], atol=0.02)  # orientation held while translating
    assert sent["ee_x.vel"] == pytest.approx(0.12, abs=1e-7)
    assert robot.safety_counters["workspace_clips"] == 0


def test_absolute_target_and_rotation(tmp_path):
    r = UR10e(UR10eConfig(backend="sim", action_mode="absolute", calibration_dir=tmp_path))
    r.connect()
    try:
        goal = _tcp(r.get_observation())
        goal[1] += 0.05
        goal[5] += 0.2
        act = dict(zip([f"ee_{a}.pos" for a in ("x", "y", "z", "roll", "pitch", "yaw")], goal, strict=True))
        _run(r, act, 20)
        time.sleep(0.5)
        end = _tcp(r.get_observation())
        np.testing.assert_allclose(end, goal, atol=5e-3)
    finally:
        r.disconnect()


def test_target_outside_workspace_is_clipped_and_counted(robot):
    # Straight down through the table: each step is allowed, but z must stop at the box floor.
    lo = robot.config.safety.workspace_min[2]
    sent = {}
    # At the nominal rate the step limit allows 0.25 m/s: ~1.6 s from home (z ~ 0.4 m) to the floor. Bound the
    # loop by steps, not by wall time, so a busy host only makes it slower, not flaky.
    for _ in range(400):
        sent = robot.send_action({"ee_z.vel": -1.5})
        time.sleep(1.0 / robot.config.control_hz)
        if robot.safety_counters["workspace_clips"] >= 3:
            break
    assert robot.safety_counters["workspace_clips"] >= 3
    assert robot.safety_counters["step_clips"] > 0  # 1.5 m/s is beyond the speed limit too
    assert robot._target[2] == pytest.approx(lo)
    assert abs(sent["ee_z.vel"]) <= robot.config.safety.max_linear_speed + 1e-7
    time.sleep(0.5)
    assert _tcp(robot.get_observation())[2] >= lo - 5e-3


def test_nan_action_raises_and_stops(robot):
    _run(robot, {"ee_x.vel": 0.24}, 5)
    with pytest.raises(UnsafeActionError, match="non-finite"):
        robot.send_action({"ee_x.vel": float("nan"), "gripper.pos": 1.0})
    assert robot.safety_counters["rejected_actions"] == 1
    time.sleep(0.3)
    v = np.abs(robot.backend.joint_velocities()).max()
    assert v < 0.02, v
    with pytest.raises(UnsafeActionError):
        robot.send_action({"ee_y.vel": float("inf")})


def test_watchdog_stops_arm_when_commands_stop(robot):
    _run(robot, {"ee_x.vel": 0.24}, 5)
    assert robot.safety_counters["watchdog_stops"] == 0
    time.sleep(robot.config.safety.watchdog_timeout_s + 0.4)
    assert robot.safety_counters["watchdog_stops"] == 1
    assert robot.watchdog.tripped
    np.testing.assert_allclose(robot.backend._q_des, robot.backend._q_set)
    assert np.abs(robot.backend.joint_velocities()).max() < 0.02
    robot.send_action({"ee_x.vel": 0.0})  # a new command re-arms it
    assert not robot.watchdog.tripped


def test_fault_stops_and_raises_clear_error(robot):
    robot.backend.inject_fault("protective stop")
    with pytest.raises(RobotFaultError, match="protective stop"):
        robot.send_action({"ee_x.vel": 0.03})
    with pytest.raises(RobotFaultError):
        robot.get_observation()


def test_gripper_opens_and_closes(robot):
    assert robot.get_observation()["gripper.pos"] < 0.05
    _run(robot, {"gripper.pos": 1.0}, 20)
    time.sleep(0.3)
    assert robot.get_observation()["gripper.pos"] > 0.95
    _run(robot, {"gripper.pos": 0.3}, 20)
    time.sleep(0.3)
    assert robot.get_observation()["gripper.pos"] == pytest.approx(0.3, abs=0.03)


def test_depth_and_pointcloud_match_scene(robot):
    obs = robot.get_observation()
    info = robot.camera_infos()["front"]
    assert (info.width, info.height) == (128, 128)
    # The pixel row through the optical centre sees the look-at point on the table: its depth equals the
    # distance from the camera to it along the optical axis.
    cam = np.array(robot.config.sim_camera_pos)
    look = np.array(robot.config.sim_camera_lookat)
    center_depth_m = obs["front_depth"][64, 64, 0] / 1000.0
    axis = info.extrinsic[:3, 2]
    # ray through the centre pixel hits the table plane z = 0
    ray = info.extrinsic[:3, :3] @ np.array([(64 - info.cx) / info.fx, (64 - info.cy) / info.fy, 1.0])
    expected = -cam[2] / ray[2]
    assert center_depth_m == pytest.approx(expected, abs=2e-3)
    assert np.dot(look - cam, axis) > 0
    from lerobot_focal.robots.ur10e.camera_info import depth_to_pointcloud
    from lerobot_focal.robots.ur10e.twin.scene import TABLE_TOP_BOX

    box = TABLE_TOP_BOX
    pc = depth_to_pointcloud(obs["front_depth"], info, *box, 512)
    assert pc.shape == (512, 3) and pc.dtype == np.float32
    # A box starting 3 mm above the table removes the table top (z = 0) as DP3 does: what is left is the objects
    # and the gripper.
    assert pc[:, 2].min() >= box[0][2] - 1e-6
    cube = np.linalg.norm(pc[:, :2] - np.array([-0.65, -0.05]), axis=1) < 0.03
    assert cube.any() and pc[cube, 2].max() == pytest.approx(0.04, abs=0.006)
    # With a crop that keeps the table, the table points lie on the plane z = 0 (table height).
    full = depth_to_pointcloud(obs["front_depth"], info, (-1.1, -0.7, -0.05), (-0.2, 0.4, 0.8), 512)
    near_table = full[full[:, 2] < 0.003]
    assert len(near_table) > 200
    # (1 mm depth quantisation at a grazing view angle spreads the plane by a few mm at most)
    assert np.percentile(np.abs(near_table[:, 2]), 95) < 2e-3, np.abs(near_table[:, 2]).max()


def test_disconnect_stops_everything(tmp_path):
    r = UR10e(UR10eConfig(backend="sim", calibration_dir=tmp_path))
    r.connect()
    r.disconnect()
    assert not r.is_connected
    from lerobot.utils.errors import DeviceNotConnectedError

    with pytest.raises(DeviceNotConnectedError):
        r.get_observation()


def test_threaded_camera_serves_its_latest_frame_at_its_own_rate(tmp_path):
    """With sim_camera_fps > 0 the twin's camera renders in its own thread, as LeRobot's RealSense thread does:
    reads within one frame period get the same frame, new frames keep coming at no more than that rate, and
    they follow the arm."""
    fps = 10.0
    r = UR10e(UR10eConfig(backend="sim", calibration_dir=tmp_path, sim_camera_fps=fps))
    r.connect()
    try:
        backend = r.backend
        quick = [r.get_observation()["front_depth"] for _ in range(20)]  # ~ms apart: no render on read
        assert len({id(d) for d in quick}) <= 2
        first = quick[-1]
        seen, t0 = {id(first)}, time.perf_counter()
        frames = [first]
        while time.perf_counter() - t0 < 1.5:
            depth = r.get_observation()["front_depth"]
            if id(depth) not in seen:
                seen.add(id(depth))
                frames.append(depth)
            r.send_action({"ee_x.vel": 0.0, "ee_y.vel": 0.0, "ee_z.vel": 0.15, "ee_roll.vel": 0.0,
                           "ee_pitch.vel": 0.0, "ee_yaw.vel": 0.0, "gripper.pos": 0.0})
            time.sleep(0.01)
        assert 3 <= len(frames) <= 1.5 * fps + 2, len(frames)
        assert not np.array_equal(frames[0], frames[-1])  # the arm moved up: later frames show it
    finally:
        r.disconnect()
    assert not backend.is_connected and backend._camera_thread is None
    for bad in (-1, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="sim_camera_fps"):
            UR10eConfig(backend="sim", sim_camera_fps=bad)
