"""Configuration of the UR-10e robot (`--robot.type=ur10e`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lerobot.cameras import CameraConfig
from lerobot.robots.config import RobotConfig

from .safety import SafetyConfig

BACKENDS = ("sim", "rtde")
ACTION_MODES = ("velocity", "absolute")


@RobotConfig.register_subclass("ur10e")
@dataclass
class UR10eConfig(RobotConfig):
    """UR-10e + parallel gripper + depth camera, on the real arm (`rtde`) or its MuJoCo twin (`sim`).

    Both backends expose the same observation and action keys, so a dataset recorded in simulation and one
    recorded on hardware have the same features and a policy trained on one can be deployed on the other.
    """

    backend: str = "sim"
    # "velocity": ee_x.vel..ee_yaw.vel in m/s, rad/s (what the gamepad records); "absolute": ee_x.pos..ee_yaw.pos
    # TCP targets. Plus `gripper.pos` (opening fraction).
    action_mode: str = "velocity"
    # Nominal command rate: velocities are integrated over 1 / control_hz and the per-command step limit is
    # speed / control_hz, so set it to the --fps of lerobot-record / lerobot-rollout.
    control_hz: float = 30.0
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    # Flange -> TCP distance along the tool z axis (fingertip centre of the AG-95 at ~0.16 m).
    tcp_offset: float = 0.16
    # Crop box (base frame) and size of the point cloud computed by `UR10e.pointcloud_from_depth`.
    pointcloud_min: tuple[float, float, float] = (-1.1, -0.7, 0.003)
    pointcloud_max: tuple[float, float, float] = (-0.2, 0.4, 0.8)
    pointcloud_num_points: int = 512

    # --- sim backend -----------------------------------------------------------------------------------------
    sim_camera_name: str = "front"
    sim_camera_width: int = 128
    sim_camera_height: int = 128
    sim_camera_fovy_deg: float = 58.0  # the D435i depth stream's vertical field of view
    sim_camera_pos: tuple[float, float, float] = (-1.45, -0.15, 0.8)
    sim_camera_lookat: tuple[float, float, float] = (-0.6, -0.15, 0.05)
    # 0: each observation renders the frame of that instant (deterministic; the render counts in the loop).
    # > 0: the twin's camera renders in its own thread at this rate and an observation takes its latest frame,
    # as LeRobot's RealSense thread serves the arm's loop (e.g. 30 for the D435i at 848x480).
    sim_camera_fps: float = 0.0
    # Fraction of the UR10e's maximum joint speeds the simulated joint servo may use.
    sim_joint_speed_fraction: float = 0.5

    # --- rtde backend ----------------------------------------------------------------------------------------
    robot_ip: str = "192.168.1.10"
    # RTDE output rate asked of the controller (500 Hz on e-Series; a CB3 controller is limited to 125 Hz).
    rtde_frequency: float = 500.0
    # Bound on each blocking exchange with the controller (version handshake, dashboard request, stopScript).
    rtde_timeout_s: float = 5.0
    # Bound on ur_rtde's connect (it uploads and starts its control script) and on the script starting.
    rtde_connect_timeout_s: float = 30.0
    servo_lookahead_s: float = 0.1
    servo_gain: float = 300.0
    # Real cameras, e.g. {"front": RealSenseCameraConfig(serial_number_or_name=..., use_depth=True, ...)}.
    cameras: dict[str, CameraConfig] = field(default_factory=dict)
    # Hand-eye calibration of each real camera: x, y, z, roll, pitch, yaw (extrinsic xyz) of the OpenCV optical
    # frame in the robot base frame. Needed to express the point cloud in the base frame.
    camera_poses: dict[str, list[float]] = field(default_factory=dict)
    # "ag95" drives the DH-Robotics AG-95 over Modbus RTU; "none" runs the arm without a gripper.
    gripper: str = "ag95"
    gripper_port: str = "/dev/ttyUSB0"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.backend not in BACKENDS:
            raise ValueError(f"UR10eConfig.backend must be one of {BACKENDS}, got {self.backend!r}.")
        if self.action_mode not in ACTION_MODES:
            raise ValueError(f"UR10eConfig.action_mode must be one of {ACTION_MODES}, got {self.action_mode!r}.")
        if not (math.isfinite(self.sim_camera_fps) and self.sim_camera_fps >= 0):
            raise ValueError(f"UR10eConfig.sim_camera_fps must be >= 0 (0 renders on each read), got {self.sim_camera_fps}.")
        if self.control_hz <= 0:
            raise ValueError(f"UR10eConfig.control_hz must be positive, got {self.control_hz}.")
        lo, hi = self.safety.workspace_min, self.safety.workspace_max
        if any(a >= b for a, b in zip(lo, hi, strict=True)):
            raise ValueError(f"Safety workspace_min {lo} must be below workspace_max {hi} on every axis.")
        if self.backend == "rtde":
            missing = [name for name in self.cameras if name not in self.camera_poses]
            if missing:
                raise ValueError(
                    f"Cameras {missing} have no entry in `camera_poses`: give each real camera's hand-eye "
                    "calibration (x, y, z, roll, pitch, yaw of its optical frame in the robot base frame)."
                )
