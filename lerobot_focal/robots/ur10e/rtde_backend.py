"""The real UR-10e through UR's RTDE interface (the `ur_rtde` package), plus AG-95 and RealSense cameras.

Only the calls listed here touch the controller, so the backend can later be pointed at an RTDE emulator on
loopback (`robot_ip="127.0.0.1"`) without changes. `ur_rtde` is imported when the backend is built, not when
the plugin is imported: every `lerobot-*` command imports this plugin, and most machines have no arm.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from .backend import ArmState
from .camera_info import CameraInfo, pose_matrix
from .config_ur10e import UR10eConfig
from .kinematics import pose6_from_rotvec_pose, rotvec_pose_from_pose6
from .safety import RobotFaultError

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
        self._rtde_control, self._rtde_receive = import_ur_rtde()
        self.ctrl: Any = None
        self.recv: Any = None
        self.gripper: Any = None
        self.cameras: dict[str, Any] = {}
        self._camera_infos: dict[str, CameraInfo] = {}
        self._lock = threading.Lock()  # ur_rtde's control interface is not safe to call from two threads
        self._last_gripper_m = 0.0

    @property
    def is_connected(self) -> bool:
        return bool(self.ctrl is not None and self.recv is not None and self.recv.isConnected())

    def connect(self) -> None:
        ip, freq = self.config.robot_ip, self.config.rtde_frequency
        try:
            self.recv = self._rtde_receive.RTDEReceiveInterface(ip, freq)
            self.ctrl = self._rtde_control.RTDEControlInterface(ip, freq)
        except RuntimeError as e:
            self._close_rtde()
            raise ConnectionError(
                f"Could not open RTDE to the UR controller at {ip}: {e}. Check the network, that the robot is "
                "powered on, brakes released, in Remote Control mode, and that no other program holds RTDE."
            ) from e
        self.ctrl.setTcp([0.0, 0.0, float(self.config.tcp_offset), 0.0, 0.0, 0.0])
        self.check_health()
        self._connect_gripper()
        self._connect_cameras()

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
        try:
            if self.ctrl is not None:
                with self._lock:
                    try:
                        self.ctrl.servoStop()
                    finally:
                        self.ctrl.stopScript()
        finally:
            self._close_rtde()
            if self.gripper is not None:
                self.gripper.disconnect()
                self.gripper = None
            for cam in self.cameras.values():
                if cam.is_connected:
                    cam.disconnect()
            self.cameras = {}

    def _close_rtde(self) -> None:
        for iface in (self.ctrl, self.recv):
            if iface is not None:
                try:
                    iface.disconnect()
                except Exception:  # noqa: BLE001 - best effort while tearing down
                    logger.exception("RTDE disconnect failed")
        self.ctrl = self.recv = None

    # -- ArmBackend -------------------------------------------------------------------------------------------
    def read_state(self) -> ArmState:
        q = np.asarray(self.recv.getActualQ(), dtype=np.float64)
        pose = pose6_from_rotvec_pose(self.recv.getActualTCPPose())
        if self.gripper is not None:
            self._last_gripper_m = float(self.gripper.read_status().opening_m)
        return ArmState(q=q, tcp_pose=pose, gripper_opening_m=self._last_gripper_m)

    def servo_tcp(self, pose6: np.ndarray) -> None:
        target = rotvec_pose_from_pose6(pose6)
        dt = 1.0 / self.config.control_hz
        with self._lock:
            ok = self.ctrl.servoL(target, 0.0, 0.0, dt, self.config.servo_lookahead_s, self.config.servo_gain)
        if ok is False:
            self.check_health()
            raise RobotFaultError(
                "UR10e rejected servoL (the control script is not running). Check the teach pendant for a "
                "protective stop or a program stop, then reconnect."
            )

    def set_gripper(self, opening_m: float) -> None:
        if self.gripper is not None:
            from .ag95 import AG95_STROKE_M

            self.gripper.set_opening(opening_m / AG95_STROKE_M)

    def stop(self) -> None:
        if self.ctrl is None:
            return
        with self._lock:
            try:
                self.ctrl.servoStop()
            finally:
                self.ctrl.speedStop()

    def check_health(self) -> None:
        if self.recv is None or self.ctrl is None:
            raise RobotFaultError("UR10e (rtde): not connected; call connect() first.")
        if not self.recv.isConnected() or not self.ctrl.isConnected():
            raise RobotFaultError(
                f"UR10e (rtde): lost the RTDE connection to {self.config.robot_ip}. Motion has been stopped; "
                "check the network cable / controller, then reconnect."
            )
        if self.recv.isEmergencyStopped():
            raise RobotFaultError("UR10e (rtde): emergency stop is active. Release it on the pendant and reconnect.")
        if self.recv.isProtectiveStopped():
            raise RobotFaultError(
                "UR10e (rtde): protective stop. Clear the cause, unlock the protective stop on the pendant, then "
                "reconnect."
            )
        mode = int(self.recv.getSafetyMode())
        if mode not in _SAFETY_MODES_OK:
            raise RobotFaultError(
                f"UR10e (rtde): safety mode is {_SAFETY_MODE_NAMES.get(mode, mode)}; the arm cannot move. "
                "Resolve it on the teach pendant, then reconnect."
            )

    def read_cameras(self) -> dict[str, tuple[np.ndarray | None, np.ndarray | None]]:
        frames: dict[str, tuple[np.ndarray | None, np.ndarray | None]] = {}
        for name, cam in self.cameras.items():
            rgb = cam.read_latest() if getattr(cam, "use_rgb", True) else None
            depth = cam.read_latest_depth() if getattr(cam, "use_depth", False) else None
            frames[name] = (rgb, depth)
        return frames

    def camera_infos(self) -> dict[str, CameraInfo]:
        return dict(self._camera_infos)
