"""The real UR-10e through UR's RTDE interface (the `ur_rtde` package), plus AG-95 and RealSense cameras.

ur_rtde is treated as untrusted (see :mod:`.rtde_session`): it runs in a child process, and the driver
believes the controller's state, not return values. Before and after every command it checks the newest
state: both interfaces connected, the controller's timestamp still advancing, no protective / emergency stop,
a safety mode in which the arm may move, and the control script running. No call in the control loop waits
on ur_rtde; commands are sent without blocking and refusals come back as events. `ur_rtde` is imported (by the
child) only when the backend connects: every `lerobot-*` command imports this plugin, and most machines have no
arm.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..backend import ArmState
from ..camera_info import CameraInfo, pose_matrix
from ..config_ur10e import UR10eConfig
from ..kinematics import pose6_from_rotvec_pose, rotvec_pose_from_pose6
from ..safety import RobotFaultError
from .rtde_session import (
    PROTECTIVE_STOP_RELEASED,
    DashboardClient,
    RtdeSession,
    SessionError,
    probe_controller_version,
)

logger = logging.getLogger(__name__)

# ur_rtde's SafetyMode values in which the arm may move (1 = NORMAL, 2 = REDUCED).
_SAFETY_MODES_OK = (1, 2)
_SAFETY_MODE_NAMES = {
    1: "NORMAL",
    2: "REDUCED",
    3: "PROTECTIVE_STOP",
    4: "RECOVERY",
    5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP",
    7: "ROBOT_EMERGENCY_STOP",
    8: "VIOLATION",
    9: "FAULT",
    10: "VALIDATE_JOINT_ID",
    11: "UNDEFINED_SAFETY_MODE",
    12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}
_STATUS_BIT_PROGRAM_RUNNING = 1 << 1  # robot_status_bits
# How long after a refusal the state may take to show its cause (see check_health): many RTDE periods even at
# 125 Hz, and well under one control period of a 10 Hz loop.
REFUSAL_GRACE_S = 0.1
_RUNTIME_STATE_NAMES = {0: "STOPPING", 1: "STOPPED", 2: "PLAYING", 3: "PAUSING", 4: "PAUSED", 5: "RESUMING"}


def _script_running(values: dict[str, Any]) -> bool:
    """Both views agree that ur_rtde's control script runs: the controller's status bits and the client's own."""
    return bool(int(values.get("robot_status_bits", 0)) & _STATUS_BIT_PROGRAM_RUNNING and values.get("program_running"))


def import_ur_rtde() -> tuple[Any, Any]:
    """Return (rtde_control, rtde_receive) or raise an ImportError that says how to install them."""
    try:
        import rtde_control
        import rtde_receive
    except ImportError as e:
        raise ImportError(
            "The UR10e 'rtde' backend needs the `ur-rtde` package, which is not installed. Install the robot "
            "extra: `pip install 'lerobot_policy_focal[robot]'` (or `pip install 'ur-rtde>=1.6'`), or use "
            "`--robot.backend=sim` to run without hardware."
        ) from e
    return rtde_control, rtde_receive


class RtdeBackend:
    """ArmBackend for the real arm (see module docstring)."""

    def __init__(self, config: UR10eConfig):
        self.config = config
        import_ur_rtde()  # fail early, with the install hint, when the package is missing
        self.session: RtdeSession | None = None
        self.controller_version: tuple[int, int, int, int] | None = None
        self.gripper: Any = None
        self.cameras: dict[str, Any] = {}
        self._camera_infos: dict[str, CameraInfo] = {}
        self._last_gripper_m = 0.0
        self._failures_seen = 0
        # The controller's state may stall this long (a network blip) before the controller counts as lost.
        self.stale_after_s = config.safety.watchdog_timeout_s if config.safety.watchdog_timeout_s > 0 else 0.5

    @property
    def is_connected(self) -> bool:
        s = self.session
        if s is None or s.dead is not None:
            return False
        v = s.snapshot.values
        return bool(v.get("recv_connected") and v.get("ctrl_connected"))

    def connect(self) -> None:
        ip = self.config.robot_ip
        self.controller_version = probe_controller_version(ip, timeout_s=self.config.rtde_timeout_s)
        major = self.controller_version[0]
        frequency = float(self.config.rtde_frequency)
        if major <= 3:
            frequency = min(frequency, 125.0)  # a CB3 controller streams RTDE at 125 Hz at most
        session = RtdeSession(ip, frequency, snapshot_period_s=min(0.01, 0.5 / self.config.control_hz))
        try:
            session.start(timeout_s=self.config.rtde_connect_timeout_s)
        except SessionError as e:
            raise ConnectionError(
                f"Could not open RTDE to the UR controller at {ip} ({self._version_str()}): {e}. Check the network, "
                "that the robot is powered on, brakes released, in Remote Control mode, and that no other program "
                "holds RTDE (a second control client is refused with IN_USE)."
            ) from e
        self.session = session
        self._failures_seen = 0  # counts this session's refusals (a reconnect starts a new list)
        try:
            # ur_rtde 1.6.5 does not upload its script to PolyScope X: only a program started there could run it.
            wait_s = min(self.config.rtde_connect_timeout_s, 5.0) if major >= 10 else self.config.rtde_connect_timeout_s
            if not session.wait_for(_script_running, timeout_s=wait_s):
                hint = (
                    " ur_rtde 1.6.5 does not upload its control script to a PolyScope X (10.x) controller (its "
                    "constructor returns without it); use an e-Series 5.x controller or URSim 5.x."
                    if major >= 10
                    else " Check the teach pendant for a popup or a protective stop, then reconnect."
                )
                raise ConnectionError(
                    f"UR controller at {ip} ({self._version_str()}): ur_rtde's control script is not running "
                    f"{wait_s:.0f} s after connecting.{hint}"
                )
            session.send("setTcp", [0.0, 0.0, float(self.config.tcp_offset), 0.0, 0.0, 0.0])
            self.check_health()
        except BaseException:
            self._close_session()
            raise
        self._connect_gripper()
        self._connect_cameras()

    def _version_str(self) -> str:
        v = self.controller_version
        return "controller version " + ".".join(map(str, v)) if v else "controller version unknown"

    def _connect_gripper(self) -> None:
        if self.config.gripper == "none":
            return
        if self.config.gripper != "ag95":
            raise ValueError(f"Unknown gripper {self.config.gripper!r}; use 'ag95' or 'none'.")
        from .ag95 import AG95Config, AG95Gripper

        self.gripper = AG95Gripper(AG95Config(port=self.config.gripper_port))
        self.gripper.connect()

    def _connect_cameras(self) -> None:
        from lerobot.cameras.utils import make_cameras_from_configs

        self.cameras = make_cameras_from_configs(self.config.cameras)
        for name, cam in self.cameras.items():
            cam.connect()
            if getattr(cam, "use_depth", False):
                self._camera_infos[name] = self._realsense_info(name, cam)

    def _realsense_info(self, name: str, cam: Any) -> CameraInfo:
        """Depth-stream intrinsics from the running RealSense profile (LeRobot's camera does not keep them)."""
        import pyrealsense2 as rs

        if int(getattr(cam.config, "rotation", 0)) != 0:
            raise ValueError(
                f"Camera {name!r}: rotated depth images would invalidate the factory intrinsics; "
                "set rotation to 0 for depth cameras."
            )
        profile = cam.rs_profile.get_stream(rs.stream.depth).as_video_stream_profile()
        intr = profile.get_intrinsics()
        scale = cam.rs_profile.get_device().first_depth_sensor().get_depth_scale()
        x, y, z, roll, pitch, yaw = self.config.camera_poses[name]
        rot = Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()
        return CameraInfo(
            width=int(intr.width),
            height=int(intr.height),
            fx=float(intr.fx),
            fy=float(intr.fy),
            cx=float(intr.ppx),
            cy=float(intr.ppy),
            T_base_cam=pose_matrix(np.array([x, y, z]), rot),
            depth_scale=float(scale),
        )

    def disconnect(self) -> None:
        healthy = (
            self.session is not None
            and self.session.dead is None
            and self.is_connected
            and time.monotonic() - self.session.snapshot.fresh_at <= self.stale_after_s
        )
        try:
            if healthy:
                self._send_stops()
                try:
                    self.session.call("stopScript", timeout_s=self.config.rtde_timeout_s)
                except SessionError as e:
                    logger.warning("UR10e: stopping the control script failed: %s", e)
        finally:
            # A lost controller has nothing to hear: end the client at once instead of waiting on ur_rtde.
            # ur_rtde's own disconnect can take seconds; the script is already stopped, so do not wait long.
            self._close_session(timeout_s=1.0 if healthy else 0.0)
            if self.gripper is not None:
                self.gripper.disconnect()
                self.gripper = None
            for cam in self.cameras.values():
                if cam.is_connected:
                    cam.disconnect()
            self.cameras = {}

    def _close_session(self, timeout_s: float = 3.0) -> None:
        if self.session is not None:
            self.session.close(timeout_s)
        self.session = None

    # -- ArmBackend -------------------------------------------------------------------------------------------
    def read_state(self) -> ArmState:
        v = self._values()
        q = np.asarray(v["q"], dtype=np.float64)
        pose = pose6_from_rotvec_pose(v["tcp"])
        if self.gripper is not None:
            self._last_gripper_m = float(self.gripper.read_status().opening_m)
        return ArmState(q=q, tcp_pose=pose, gripper_opening_m=self._last_gripper_m)

    def _values(self) -> dict[str, Any]:
        if self.session is None:
            raise RobotFaultError("UR10e (rtde): not connected; call connect() first.")
        return self.session.snapshot.values

    def servo_tcp(self, pose6: np.ndarray) -> None:
        self.check_health()
        target = rotvec_pose_from_pose6(pose6)
        dt = 1.0 / self.config.control_hz
        try:
            self.session.send("servoL", target, 0.0, 0.0, dt, self.config.servo_lookahead_s, self.config.servo_gain)
        except SessionError as e:
            raise self._lost(str(e)) from e
        self.check_health()

    def set_gripper(self, opening_m: float) -> None:
        if self.gripper is not None:
            from .ag95 import AG95_STROKE_M

            self.gripper.set_opening(opening_m / AG95_STROKE_M)

    def stop(self) -> None:
        """Stop the arm: servoStop ends servoL and speedStop ends speed mode (servoStop alone does not)."""
        if self.session is None or self.session.dead is not None:
            return
        if not self.session.snapshot.values.get("program_running"):
            return  # no script to command: the controller already holds the arm (protective stop, stopped program)
        self._send_stops()

    def _send_stops(self) -> None:
        try:
            self.session.send("servoStop", 10.0)
            self.session.send("speedStop", 10.0)
        except SessionError:
            pass  # the controller is gone: its own watchdog stops the arm; check_health reports it

    def _lost(self, why: str) -> RobotFaultError:
        return RobotFaultError(
            f"UR10e (rtde): lost the controller at {self.config.robot_ip}: {why}. Motion commands have stopped; "
            "check the network cable and the controller, then reconnect."
        )

    def check_health(self) -> None:
        s = self.session
        if s is None:
            raise RobotFaultError("UR10e (rtde): not connected; call connect() first.")
        if s.dead is not None:
            raise self._lost(f"the ur_rtde client process ended ({s.dead})")
        v = s.snapshot.values
        if "error" in v:
            raise self._lost(f"reading its state failed ({v['error']})")
        if not v.get("recv_connected") or not v.get("ctrl_connected"):
            raise self._lost("the RTDE connection is closed")
        age = time.monotonic() - s.snapshot.fresh_at
        if age > self.stale_after_s:
            raise self._lost(f"no new state from it for {age:.2f} s (limit {self.stale_after_s:.2f} s)")
        if v.get("emergency_stopped"):
            raise RobotFaultError("UR10e (rtde): emergency stop is active. Release it on the pendant and reconnect.")
        if v.get("protective_stopped"):
            raise RobotFaultError(
                f"UR10e (rtde): protective stop (safety status bits {v.get('safety_status_bits', 0):#x}): the "
                "controller stopped the arm (a collision, a limit, or a triggered stop). Clear the cause, then call "
                "robot.recover() (it unlocks the stop once the controller allows it, 5 s after it occurred, and "
                "restarts the control script) or unlock it on the pendant and reconnect."
            )
        mode = int(v.get("safety_mode", 1))
        if mode not in _SAFETY_MODES_OK:
            raise RobotFaultError(
                f"UR10e (rtde): safety mode is {_SAFETY_MODE_NAMES.get(mode, mode)}; the arm cannot move. "
                "Resolve it on the teach pendant, then reconnect."
            )
        # The receive interface's status bits, not the control interface's isProgramRunning(): they arrive in the
        # same RTDE package as the safety bits above, so a protective stop is named as such, not as a stopped
        # program seen a few milliseconds earlier on the other connection.
        if not int(v.get("robot_status_bits", 0)) & _STATUS_BIT_PROGRAM_RUNNING:
            state = _RUNTIME_STATE_NAMES.get(int(v.get("runtime_state", -1)), v.get("runtime_state"))
            raise RobotFaultError(
                f"UR10e (rtde): ur_rtde's control script is not running on the controller (runtime state "
                f"{state}); a program was stopped or paused from the pendant or the dashboard. Call "
                "robot.recover() to re-upload it, or reconnect."
            )
        if len(s.failures) > self._failures_seen:
            # ur_rtde's control connection can report a refusal a few RTDE packages before the receive
            # connection's state explains it (a protective stop stops the script; both arrive within ms). A
            # refusal is unexplained only once state that arrived well after it still looks healthy; until then
            # the next check names the real cause above. The refused command moved nothing meanwhile. The grace
            # counts from the first refusal not yet reported, so a refusal every control step cannot extend it.
            first_arrived_at = s.failures[self._failures_seen][2]
            if s.snapshot.received_at < first_arrived_at + REFUSAL_GRACE_S:
                return
            method, value, _ = s.failures[-1]
            self._failures_seen = len(s.failures)
            raise RobotFaultError(
                f"UR10e (rtde): the controller refused {method} ({value!r}) although its state looked healthy. "
                "Check the teach pendant, then reconnect."
            )

    def recover(self, timeout_s: float = 20.0) -> None:
        """Unlock a protective stop and restart the control script; returns once the script runs again.

        The controller refuses to unlock during the first 5 s after a protective stop, so this retries the
        unlock until it is accepted or `timeout_s` passes. Then a paused program is stopped, the script is
        re-uploaded, and this waits (bounded) until the controller reports it running.
        """
        s = self.session
        if s is None or s.dead is not None or not self.is_connected:
            raise self._lost("cannot recover without a connection; reconnect instead")
        if self.controller_version and self.controller_version[0] >= 10:
            raise RobotFaultError("UR10e (rtde): PolyScope X has no dashboard server; recover on the pendant.")
        dash = DashboardClient(self.config.robot_ip, timeout_s=self.config.rtde_timeout_s)
        deadline = time.monotonic() + timeout_s
        if s.snapshot.values.get("protective_stopped"):
            reply = dash.unlock_protective_stop(timeout_s)
            if not reply.startswith(PROTECTIVE_STOP_RELEASED):
                raise RobotFaultError(
                    f"UR10e (rtde): the protective stop was not unlocked within {timeout_s:.0f} s: {reply!r}"
                )
            dash.request("close safety popup")
            released = s.wait_for(lambda v: not v.get("protective_stopped"),
                                  timeout_s=max(0.1, deadline - time.monotonic()))
            if not released:
                raise RobotFaultError("UR10e (rtde): the controller still reports a protective stop after the unlock.")
        if not _script_running(s.snapshot.values):
            if int(s.snapshot.values.get("runtime_state", 1)) == 4:  # paused: end it so the script can be uploaded
                dash.request("stop")
            s.wait_for(lambda v: int(v.get("runtime_state", 1)) != 4, timeout_s=2.0)
            try:
                s.call("reuploadScript", timeout_s=max(0.1, min(5.0, deadline - time.monotonic())))
            except SessionError as e:
                raise RobotFaultError(f"UR10e (rtde): re-uploading the control script failed: {e}") from e
            if not s.wait_for(_script_running, timeout_s=max(0.1, deadline - time.monotonic())):
                raise RobotFaultError(
                    f"UR10e (rtde): the control script was re-uploaded but is not running within {timeout_s:.0f} s."
                )
            s.send("setTcp", [0.0, 0.0, float(self.config.tcp_offset), 0.0, 0.0, 0.0])
        self._failures_seen = len(s.failures)
        self.check_health()

    def read_cameras(self) -> dict[str, tuple[np.ndarray | None, np.ndarray | None]]:
        frames: dict[str, tuple[np.ndarray | None, np.ndarray | None]] = {}
        for name, cam in self.cameras.items():
            rgb = cam.read_latest() if getattr(cam, "use_rgb", True) else None
            depth = cam.read_latest_depth() if getattr(cam, "use_depth", False) else None
            frames[name] = (rgb, depth)
        return frames

    def camera_infos(self) -> dict[str, CameraInfo]:
        return dict(self._camera_infos)
