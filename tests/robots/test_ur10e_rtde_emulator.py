"""The rtde backend against an emulated UR controller over loopback, with ur_rtde's real receive interface.

The emulator (``rtde_emulator.RtdeEmulator``) speaks RTDE protocol v2 on port 30004 with the MuJoCo twin behind
it, in a child process (ur_rtde's bindings keep the GIL while blocking). ``RTDEReceiveInterface`` is the real
one from the ``ur-rtde`` wheel. ``RTDEControlInterface`` cannot be served by a protocol emulator (it needs the
dashboard server and runs an uploaded URScript program; the first test pins that down), so the control side
is ``FakeRTDEControlInterface`` — the one fake, applying servoL/stop to the same simulated arm.
"""

from __future__ import annotations

import random
import time
import types

import numpy as np
import pytest
from lerobot.utils.errors import DeviceNotConnectedError

rtde_receive = pytest.importorskip("rtde_receive")
rtde_control = pytest.importorskip("rtde_control")
pytest.importorskip("mujoco")

from lerobot_focal.robots.ur10e import UR10e, UR10eConfig  # noqa: E402
from lerobot_focal.robots.ur10e import rtde_backend  # noqa: E402
from lerobot_focal.robots.ur10e.kinematics import pose6_from_rotvec_pose  # noqa: E402
from lerobot_focal.robots.ur10e.rtde_emulator import FakeRTDEControlInterface, RtdeEmulatorProcess  # noqa: E402
from lerobot_focal.robots.ur10e.safety import RobotFaultError, SafetyConfig  # noqa: E402


@pytest.fixture(scope="module")
def emulator():
    # ur_rtde always dials port 30004: a random loopback address keeps parallel runs apart.
    host = f"127.{random.randint(1, 250)}.{random.randint(1, 250)}.{random.randint(2, 250)}"
    with RtdeEmulatorProcess(host) as emu:
        yield emu


def test_control_interface_needs_the_dashboard_server(emulator):
    """Why the control side is faked: ur_rtde's control interface first dials the dashboard server (29999),
    which a protocol emulator does not provide, before it would upload and run its URScript program."""
    with pytest.raises(RuntimeError, match="dashboard"):
        rtde_control.RTDEControlInterface(emulator.host, 125.0)


def test_real_receive_interface_reads_the_simulated_arm(emulator):
    recv = rtde_receive.RTDEReceiveInterface(emulator.host, 125.0)
    try:
        time.sleep(0.2)
        assert recv.isConnected()
        q, tcp, _ = emulator.arm_state()
        np.testing.assert_allclose(recv.getActualQ(), q, atol=1e-6)
        np.testing.assert_allclose(pose6_from_rotvec_pose(recv.getActualTCPPose()), tcp, atol=1e-6)
        assert recv.getSafetyMode() == 1 and recv.getRobotMode() == 7
        assert not recv.isProtectiveStopped() and not recv.isEmergencyStopped()
        t0 = recv.getTimestamp()
        time.sleep(0.3)
        assert recv.getTimestamp() - t0 == pytest.approx(0.3, abs=0.15)  # the stream keeps flowing
        assert "actual_TCP_pose" in emulator.status()["requested_outputs"]
    finally:
        recv.disconnect()


@pytest.fixture
def robot(emulator, monkeypatch, tmp_path):
    fakes: list[FakeRTDEControlInterface] = []

    def make_control(ip, freq):
        fakes.append(FakeRTDEControlInterface(emulator, ip, freq))
        return fakes[-1]

    fake_module = types.SimpleNamespace(RTDEControlInterface=make_control)
    monkeypatch.setattr(rtde_backend, "import_ur_rtde", lambda: (fake_module, rtde_receive))
    emulator.clear_faults()
    cfg = UR10eConfig(
        backend="rtde",
        robot_ip=emulator.host,
        rtde_frequency=125.0,
        gripper="none",
        calibration_dir=tmp_path,
        safety=SafetyConfig(watchdog_timeout_s=1.0),
    )
    r = UR10e(cfg)
    r.connect()
    r.fake_control = fakes[-1]
    yield r
    if r.is_connected:
        r.disconnect()


def _tcp(obs):
    return np.array([obs[f"ee_{a}.pos"] for a in ("x", "y", "z", "roll", "pitch", "yaw")])


def test_robot_moves_through_rtde_and_reads_back_through_real_receive(robot, emulator):
    assert robot.fake_control.tcp_offset == [0.0, 0.0, robot.config.tcp_offset, 0.0, 0.0, 0.0]
    start = _tcp(robot.get_observation())
    for _ in range(20):
        robot.send_action({"ee_y.vel": 0.15})
        time.sleep(1 / robot.config.control_hz)
    time.sleep(0.4)
    end = _tcp(robot.get_observation())  # read through the real RTDEReceiveInterface
    assert end[1] - start[1] > 0.05, (start, end)
    np.testing.assert_allclose(end[[0, 2]], start[[0, 2]], atol=0.01)
    np.testing.assert_allclose(end, emulator.arm_state()[1], atol=2e-3)


def test_dropped_connection_mid_episode_stops_arm_with_clear_error(robot, emulator):
    for _ in range(5):
        robot.send_action({"ee_x.vel": 0.2})
        time.sleep(1 / robot.config.control_hz)
    emulator.drop_connections()  # the network cable is pulled while the arm moves
    # Let ur_rtde's receive thread notice first (the race that once surfaced LeRobot's generic "not connected"
    # instead of the clear fault): the next command must still report the lost connection itself.
    deadline = time.monotonic() + 0.5
    while robot.backend.recv.isConnected() and time.monotonic() < deadline:
        time.sleep(0.01)
    with pytest.raises(RobotFaultError, match="lost the RTDE connection"):
        for _ in range(50):  # the receive thread notices within a few ms; the watchdog too
            robot.send_action({"ee_x.vel": 0.2})
            time.sleep(1 / robot.config.control_hz)
    calls = robot.fake_control.calls
    assert "servoStop" in calls[calls.index("servoL") :] and "speedStop" in calls
    time.sleep(0.3)
    assert emulator.arm_state()[2] < 0.02  # joint speeds ~0: the arm holds still
    assert not robot.is_connected  # and it says so: LeRobot's own "not connected" error from here on
    with pytest.raises(DeviceNotConnectedError):
        robot.get_observation()


def test_protective_stop_is_reported_and_motion_refused(robot, emulator):
    robot.send_action({"ee_x.vel": 0.0})
    emulator.protective_stop()
    time.sleep(0.1)
    with pytest.raises(RobotFaultError, match="protective stop"):
        robot.send_action({"ee_x.vel": 0.1})
    assert robot.fake_control.calls[-2:] == ["servoStop", "speedStop"]
