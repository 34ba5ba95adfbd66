"""ur_rtde 1.6.5's real clients against the emulated UR controller: what reaches the controller's registers.

The emulator (``rtde_emulator``) serves RTDE (30004), the dashboard (29999) and the script port (30003) on a
free loopback address, in its own process, with the MuJoCo twin behind it. ``RTDEReceiveInterface`` and
``RTDEControlInterface`` are the real classes from the ``ur-rtde`` wheel; every command they send is logged by
the emulated control script with its raw registers, which is what these tests assert. The clients run in the
test process (the emulator is another process), under a hard deadline since they hold the GIL while connecting.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

rtde_receive = pytest.importorskip("rtde_receive")
rtde_control = pytest.importorskip("rtde_control")
pytest.importorskip("mujoco")

from lerobot_focal.robots.ur10e.kinematics import pose6_from_rotvec_pose  # noqa: E402
from lerobot_focal.testing.ur10e_emulator.rtde_emulator import RtdeEmulatorProcess  # noqa: E402

from .ur_emulator_support import free_loopback_host, hard_deadline, wait_still  # noqa: E402

pytestmark = pytest.mark.subprocess  # the emulated UR controller runs in its own process


@pytest.fixture(scope="module")
def emulator():
    with RtdeEmulatorProcess(free_loopback_host()) as emu:
        yield emu


@pytest.fixture(scope="module")
def clients(emulator):
    """One real receive + control client for the module (each constructor uploads the script: ~0.2 s)."""
    with hard_deadline(60):
        recv = rtde_receive.RTDEReceiveInterface(emulator.host, 125.0)
        ctrl = rtde_control.RTDEControlInterface(emulator.host, 125.0)
    yield recv, ctrl
    ctrl.stopScript()
    ctrl.disconnect()
    recv.disconnect()


def _new_commands(emulator, since: int) -> list[dict]:
    return emulator.commands(since)


def test_real_receive_interface_reads_the_twin(emulator, clients):
    recv, _ = clients
    q, tcp, _ = emulator.arm_state()
    np.testing.assert_allclose(recv.getActualQ(), q, atol=1e-4)
    np.testing.assert_allclose(pose6_from_rotvec_pose(recv.getActualTCPPose()), tcp, atol=1e-4)
    assert recv.getSafetyMode() == 1 and recv.getRobotMode() == 7
    assert not recv.isProtectiveStopped() and not recv.isEmergencyStopped()
    t0 = recv.getTimestamp()
    time.sleep(0.3)
    assert recv.getTimestamp() > t0  # the stream keeps flowing


def test_control_interface_uploads_its_script_and_reports_it_running(emulator, clients):
    _, ctrl = clients
    status = emulator.status()
    assert ctrl.isConnected() and ctrl.isProgramRunning()
    assert status["script_uploads"][-1] == "def rtde_control():"
    assert status["runtime_state"] == 2
    # The control interface's own output recipe: the 13 variables of a controller before 5.23.
    first_four = ["timestamp", "robot_status_bits", "safety_status_bits", "runtime_state"]
    assert status["requested_outputs"][-1][:4] == first_four
    assert len(status["requested_outputs"][-1]) == 13
    # A loopback address other than 127.0.0.1 makes the client ask whether the robot is in remote control.
    assert ("is in remote control", "true") in [tuple(x) for x in status["dashboard_log"]]


def test_servoL_registers_carry_pose_in_base_frame_metres_and_servo_parameters(emulator, clients):  # noqa: N802 (URScript names)
    recv, ctrl = clients
    start = np.array(recv.getActualTCPPose())
    since = emulator.status()["commands_total"]
    target = start + np.array([0.0, 0.03, -0.02, 0.0, 0.0, 0.0])  # 3 cm along +y, 2 cm down (metres)
    for _ in range(60):
        assert ctrl.servoL(target.tolist(), 0.25, 1.2, 0.008, 0.1, 300.0) is True
        time.sleep(0.008)
    ctrl.servoStop(10.0)
    cmds = _new_commands(emulator, since)
    servo = [c for c in cmds if c["name"] == "servoL"]
    assert servo, cmds
    d = {int(k): v for k, v in servo[-1]["doubles"].items()}
    np.testing.assert_allclose([d[i] for i in range(6)], target, atol=1e-12)  # x, y, z, rx, ry, rz as sent
    assert (d[6], d[7], d[8], d[9], d[10]) == pytest.approx((0.25, 1.2, 0.008, 0.1, 300.0))
    assert cmds[-1]["name"] == "servoStop" and cmds[-1]["doubles"][0] == pytest.approx(10.0)
    # The twin went where the registers said, in metres: the same base frame the receive interface reports.
    wait_still(emulator)
    np.testing.assert_allclose(recv.getActualTCPPose()[:3], target[:3], atol=3e-3)


def test_moveL_waits_for_the_motion_and_carries_speed_and_acceleration(emulator, clients):  # noqa: N802 (URScript names)
    recv, ctrl = clients
    start = np.array(recv.getActualTCPPose())
    target = start + np.array([0.05, 0.0, 0.0, 0.0, 0.0, 0.0])
    since = emulator.status()["commands_total"]
    t0 = time.monotonic()
    with hard_deadline(60):  # moveL waits up to 300 s for "done" if the script never reports it
        assert ctrl.moveL(target.tolist(), 0.2, 1.0) is True
    elapsed = time.monotonic() - t0
    (move,) = [c for c in _new_commands(emulator, since) if c["name"] == "moveL"]
    assert move["doubles"][6] == pytest.approx(0.2) and move["doubles"][7] == pytest.approx(1.0)
    assert move["ints"][1] == 0  # synchronous
    # moveL returned only once the arm had arrived: 5 cm at 0.2 m/s takes at least 0.25 s.
    assert elapsed >= 0.2
    np.testing.assert_allclose(recv.getActualTCPPose()[:3], target[:3], atol=3e-3)


def test_speedL_is_stopped_by_speedStop_not_by_servoStop(emulator, clients):  # noqa: N802 (URScript names)
    recv, ctrl = clients
    since = emulator.status()["commands_total"]
    assert ctrl.speedL([0.0, -0.04, 0.0, 0.0, 0.0, 0.0], 0.5, 0.0) is True
    time.sleep(0.3)
    ctrl.servoStop(10.0)
    time.sleep(0.3)
    assert emulator.arm_state()[2] > 0.01  # still moving: servoStop does not end speed mode
    y0 = recv.getActualTCPPose()[1]
    ctrl.speedStop(10.0)
    assert wait_still(emulator) < 1e-3
    y1 = recv.getActualTCPPose()[1]
    time.sleep(0.3)
    assert abs(recv.getActualTCPPose()[1] - y1) < 1e-3 and y1 < y0
    names = [c["name"] for c in _new_commands(emulator, since)]
    assert names == ["speedL", "servoStop", "speedStop"], names
    speed = _new_commands(emulator, since)[0]["doubles"]
    assert [speed[i] for i in range(8)] == pytest.approx([0.0, -0.04, 0.0, 0.0, 0.0, 0.0, 0.5, 0.0])


def test_second_control_client_is_refused_with_in_use_and_the_first_keeps_control(emulator, clients):
    recv, ctrl = clients
    before = emulator.status()["in_use_refusals"]
    with hard_deadline(60), pytest.raises(RuntimeError, match="already in use"):
        rtde_control.RTDEControlInterface(emulator.host, 125.0)
    assert emulator.status()["in_use_refusals"] == before + 1
    since = emulator.status()["commands_total"]
    assert ctrl.isProgramRunning()
    assert ctrl.servoL(recv.getActualTCPPose(), 0.0, 0.0, 0.008, 0.1, 300.0) is True
    ctrl.servoStop(10.0)
    assert [c["name"] for c in _new_commands(emulator, since)] == ["servoL", "servoStop"]


def test_trigger_protective_stop_reaches_the_safety_state_and_halts_the_script(emulator, clients):
    """Last in this module: it leaves the shared controller protectively stopped."""
    recv, ctrl = clients
    since = emulator.status()["commands_total"]
    assert ctrl.triggerProtectiveStop() is True
    deadline = time.monotonic() + 5
    while not recv.isProtectiveStopped() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert recv.isProtectiveStopped() and recv.getSafetyMode() == 3
    assert recv.getSafetyStatusBits() == 0x404 and recv.getRuntimeState() == 4  # program paused
    assert [c["name"] for c in emulator.commands(since)] == ["triggerProtectiveStop"]
    before = np.array(recv.getActualTCPPose())
    ctrl.servoL((before + [0, 0.05, 0, 0, 0, 0]).tolist(), 0.0, 0.0, 0.008, 0.1, 300.0)
    time.sleep(0.3)
    np.testing.assert_allclose(recv.getActualTCPPose(), before, atol=1e-4)  # a paused script moves nothing
