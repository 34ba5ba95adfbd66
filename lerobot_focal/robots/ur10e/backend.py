"""The contract between the UR10e robot class and its backends (MuJoCo twin, real arm over RTDE).

The robot class owns action semantics and safety; a backend only moves the arm to an already-safe TCP target,
reports state and health, and stops. Keeping that boundary narrow is what lets the RTDE backend later be
exercised against an emulator with the rest of the stack unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .camera_info import CameraInfo


@dataclass
class ArmState:
    q: np.ndarray  # (6,) joint positions, rad
    tcp_pose: np.ndarray  # (6,) pose6: x, y, z, roll, pitch, yaw relative to tool-down (see kinematics)
    gripper_opening_m: float


class ArmBackend(Protocol):
    def connect(self) -> None: ...

    def disconnect(self) -> None: ...

    @property
    def is_connected(self) -> bool: ...

    def read_state(self) -> ArmState: ...

    def servo_tcp(self, pose6: np.ndarray) -> None:
        """Track this (already safety-filtered) TCP target until the next one arrives."""

    def set_gripper(self, opening_m: float) -> None: ...

    def stop(self) -> None:
        """Stop arm motion now (hold the current pose). Must be safe to call from another thread."""

    def check_health(self) -> None:
        """Raise RobotFaultError if the arm cannot move (connection lost, protective/emergency stop)."""

    def read_cameras(self) -> dict[str, tuple[np.ndarray | None, np.ndarray | None]]:
        """{name: (rgb uint8 (H, W, 3) or None, depth uint16 mm (H, W, 1) or None)}."""

    def camera_infos(self) -> dict[str, CameraInfo]: ...
