"""Configuration of the UR-10e robot (`--robot.type=ur10e`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.cameras import CameraConfig
from lerobot.robots.config import RobotConfig

from lerobot_focal.config_errors import (
    reports_config_errors,
    require_choice,
    require_in_range,
    require_non_negative,
    require_positive,
)

from .safety import SafetyConfig

BACKENDS = ("sim", "rtde")
ACTION_MODES = ("velocity", "absolute")
GRIPPERS = ("ag95", "none")
#: The ranges URScript's servoL accepts for lookahead_time (s) and gain.
SERVO_LOOKAHEAD_RANGE_S = (0.03, 0.2)
SERVO_GAIN_RANGE = (100.0, 2000.0)


@RobotConfig.register_subclass("ur10e")
@reports_config_errors("--robot.type=ur10e")
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
        require_choice("backend", self.backend, BACKENDS)
        require_choice("action_mode", self.action_mode, ACTION_MODES)
        require_choice("gripper", self.gripper, GRIPPERS)
        require_positive(
            control_hz=self.control_hz, rtde_frequency=self.rtde_frequency, rtde_timeout_s=self.rtde_timeout_s,
            rtde_connect_timeout_s=self.rtde_connect_timeout_s,
            sim_camera_width=self.sim_camera_width, sim_camera_height=self.sim_camera_height,
            **{"safety.max_linear_speed": self.safety.max_linear_speed,
               "safety.max_angular_speed": self.safety.max_angular_speed},
        )
        require_non_negative(tcp_offset=self.tcp_offset)
        if self.sim_camera_fps != 0:
            require_positive(sim_camera_fps=self.sim_camera_fps)  # 0 renders on each read
        require_in_range("sim_camera_fovy_deg", self.sim_camera_fovy_deg, 0.0, 180.0, low_open=True, high_open=True)
        require_in_range("sim_joint_speed_fraction", self.sim_joint_speed_fraction, 0.0, 1.0, low_open=True,
                         why="It is a fraction of the UR10e's maximum joint speeds.")
        require_in_range("servo_lookahead_s", self.servo_lookahead_s, *SERVO_LOOKAHEAD_RANGE_S,
                         why="That is the range URScript's servoL accepts.")
        require_in_range("servo_gain", self.servo_gain, *SERVO_GAIN_RANGE,
                         why="That is the range URScript's servoL accepts.")
        if tuple(self.sim_camera_pos) == tuple(self.sim_camera_lookat):
            raise ValueError(f"sim_camera_pos and sim_camera_lookat are the same point {tuple(self.sim_camera_pos)}.")
        lo, hi = self.safety.workspace_min, self.safety.workspace_max
        if any(a >= b for a, b in zip(lo, hi, strict=True)):
            raise ValueError(f"safety.workspace_min {tuple(lo)} must be below safety.workspace_max {tuple(hi)} on "
                             "every axis.")
        bad_poses = {name: pose for name, pose in self.camera_poses.items() if len(pose) != 6}
        if bad_poses:
            raise ValueError(
                f"camera_poses {bad_poses} must each be 6 numbers: x, y, z (m), roll, pitch, yaw (rad) of the camera's "
                "optical frame in the robot base frame."
            )
        if self.backend == "rtde":
            missing = [name for name in self.cameras if name not in self.camera_poses]
            if missing:
                raise ValueError(
                    f"Cameras {missing} have no entry in `camera_poses`: give each real camera's hand-eye "
                    "calibration (x, y, z, roll, pitch, yaw of its optical frame in the robot base frame)."
                )
