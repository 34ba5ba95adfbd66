"""`--robot.type=ur10e`: the UR-10e + gripper + depth camera as a LeRobot `Robot`.

Actions are end-effector commands, as the focal_gamepad teleoperator records them. Every key ends in
``.pos`` or ``.vel`` because ``lerobot-rollout`` (0.6.1) only routes robot features with those suffixes to and
from a policy:

* ``action_mode="velocity"`` (default): ``ee_x.vel, ee_y.vel, ee_z.vel`` (m/s, base frame) and ``ee_roll.vel,
  ee_pitch.vel, ee_yaw.vel`` (rad/s, about the base axes through the TCP). Each command is integrated over one
  control period (``1 / control_hz``) into a TCP target relative to the current target; missing keys count as 0.
* ``action_mode="absolute"``: ``ee_x.pos, ee_y.pos, ee_z.pos, ee_roll.pos, ee_pitch.pos, ee_yaw.pos`` in the
  base frame, angles relative to the tool-pointing-down orientation (see :mod:`.kinematics`). Absolute keys are
  accepted in either mode (that is how ``lerobot-rollout`` returns the arm to its start pose).
* ``gripper.pos``: commanded opening as a fraction, 1 = fully open (95 mm), 0 = closed; missing = unchanged.

Every command goes through :class:`.safety.SafetyFilter` (finite check, per-step speed limit, workspace box
clipping with counters) and kicks the :class:`.safety.Watchdog`; `send_action` returns the action that was
really sent, in the same keys.

Observations: ``<joint>.pos`` (rad), ``ee_x.pos .. ee_yaw.pos`` (measured TCP pose, same names and convention
as absolute actions), ``gripper.pos`` (opening fraction), ``<camera>`` RGB (H, W, 3) uint8 and
``<camera>_depth`` (H, W, 1) uint16 mm.

Point clouds: depth is recorded under LeRobot's ``{camera}_depth`` naming, and the camera intrinsics and
extrinsics (which LeRobot's RealSense camera drops) are kept by the robot in :meth:`camera_infos` and meant
to be stored with the dataset (:func:`.camera_info.save_camera_infos`). The robot makes no point cloud: a
``focal`` policy trained with ``--policy.depth_cloud.from_depth=observation.images.<camera>_depth`` makes it from
the depth in its own preprocessor, at training and rollout, with the crop and point count its checkpoint holds
(``lerobot_focal.policy.depth_cloud_settings``), the one copy of those settings.
"""

from __future__ import annotations

import logging
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from lerobot.lerobot_types import RobotAction, RobotObservation
from lerobot.robots.robot import Robot
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected
from scipy.spatial.transform import Rotation

from .backend import ArmBackend
from .camera_info import CameraInfo, save_camera_infos
from .config_ur10e import UR10eConfig
from .kinematics import AG95_MAX_OPENING_M, JOINT_NAMES, apply_delta, matrix_from_pose6, pose_difference
from .safety import RobotFaultError, SafetyFilter, UnsafeActionError, Watchdog

logger = logging.getLogger(__name__)

POSE_AXES = ("x", "y", "z", "roll", "pitch", "yaw")
VELOCITY_KEYS = tuple(f"ee_{a}.vel" for a in POSE_AXES)
ABSOLUTE_KEYS = tuple(f"ee_{a}.pos" for a in POSE_AXES)
TCP_KEYS = ABSOLUTE_KEYS  # the measured pose uses the names of the absolute command
GRIPPER_KEY = "gripper.pos"
# Tracking error beyond which deltas re-anchor on the measured pose instead of the last target.
_REANCHOR_M = 0.05
_REANCHOR_RAD = 0.3


def make_backend(config: UR10eConfig) -> ArmBackend:
    if config.backend == "sim":
        from .twin.sim_backend import SimBackend

        return SimBackend(config)
    from .rtde.rtde_backend import RtdeBackend

    return RtdeBackend(config)


class UR10e(Robot):
    """UR-10e arm with AG-95-style gripper and a depth camera; see the module docstring for keys and units."""

    config_class = UR10eConfig
    name = "ur10e"

    def __init__(self, config: UR10eConfig):
        super().__init__(config)
        self.config = config
        self.backend: ArmBackend | None = None
        # A lost connection must reach the caller once as the clear RobotFaultError, not as LeRobot's generic
        # "not connected" that the decorators raise when is_connected turns False between two calls.
        self._fault_reported = False
        self.safety = SafetyFilter(config.safety, config.control_hz)
        self.watchdog: Watchdog | None = None
        self._gripper_cmd: float | None = None
        self._target: np.ndarray | None = None
        self.commands_sent = 0  # commands that reached the backend since construction
        self.commanded_path_m = 0.0  # summed TCP displacement of those commands (how far they asked to move)

    # -- features (valid while disconnected) ------------------------------------------------------------------
    def _camera_shapes(self) -> dict[str, tuple[int, int, bool, bool]]:
        """{name: (height, width, has_rgb, has_depth)} from the config alone."""
        if self.config.backend == "sim":
            c = self.config
            return {c.sim_camera_name: (c.sim_camera_height, c.sim_camera_width, True, True)}
        return {
            name: (cfg.height, cfg.width, getattr(cfg, "use_rgb", True), getattr(cfg, "use_depth", False))
            for name, cfg in self.config.cameras.items()
        }

    @property
    def cameras(self) -> dict[str, Any]:
        """{name: camera} — LeRobot's real camera objects on the rtde backend while connected, else the names
        (with None). lerobot-record / lerobot-rollout size their image writers with ``len(robot.cameras)``."""
        live = getattr(self.backend, "cameras", None)
        if isinstance(live, dict) and live:
            return live
        return dict.fromkeys(self._camera_shapes())

    @cached_property
    def observation_features(self) -> dict[str, type | tuple]:
        features: dict[str, type | tuple] = {f"{j}.pos": float for j in JOINT_NAMES}
        features.update({k: float for k in TCP_KEYS})
        features[GRIPPER_KEY] = float
        for name, (h, w, rgb, depth) in self._camera_shapes().items():
            if rgb:
                features[name] = (h, w, 3)
            if depth:
                features[f"{name}_depth"] = (h, w, 1)
        return features

    @cached_property
    def action_features(self) -> dict[str, type]:
        keys = VELOCITY_KEYS if self.config.action_mode == "velocity" else ABSOLUTE_KEYS
        return {**{k: float for k in keys}, GRIPPER_KEY: float}

    # -- lifecycle --------------------------------------------------------------------------------------------
    @property
    def is_connected(self) -> bool:
        if self.backend is None:
            return False
        return self.backend.is_connected or not self._fault_reported

    @property
    def is_calibrated(self) -> bool:
        return True  # the controller knows its own kinematics; nothing to calibrate from LeRobot

    def calibrate(self) -> None:
        pass

    def configure(self) -> None:
        pass

    @check_if_already_connected
    def connect(self, calibrate: bool = True) -> None:
        backend = make_backend(self.config)
        backend.connect()
        self.backend = backend
        self._fault_reported = False
        self._target = None
        self.watchdog = Watchdog(
            self.config.safety.watchdog_timeout_s, on_timeout=backend.stop, health_check=backend.check_health
        )
        self.watchdog.start()
        self._save_camera_infos()
        logger.info("%s connected (backend=%s).", self, self.config.backend)

    @property
    def camera_infos_path(self) -> Path:
        """Where :meth:`connect` writes the depth cameras' intrinsics + extrinsics (JSON, see camera_info.py)."""
        return self.calibration_dir / f"{self.id or self.name}_cameras.json"

    def _save_camera_infos(self) -> None:
        """Keep the intrinsics LeRobot's cameras drop, next to the robot's calibration, on every connect.

        A focal policy trained on a dataset this robot recorded finds the file from the dataset's robot type
        (`lerobot_focal.policy.depth_pointcloud_step.resolve_camera_info_path`) and keeps the camera's entry in its
        checkpoint; :func:`.camera_info.load_camera_infos` reads it back.
        """
        infos = self.backend.camera_infos()
        if infos:
            save_camera_infos(self.camera_infos_path, infos)
            logger.info("%s: depth camera intrinsics/extrinsics written to %s", self, self.camera_infos_path)

    @check_if_not_connected
    def disconnect(self) -> None:
        if self.watchdog is not None:
            self.watchdog.stop()
            self.safety.counters.watchdog_stops += self.watchdog.trips  # keep the count past this connection
            self.watchdog = None
        backend, self.backend = self.backend, None
        self._fault_reported = False
        try:
            backend.stop()
        except Exception:  # noqa: BLE001 - the connection may already be gone; disconnect anyway
            logger.exception("Stopping the UR10e during disconnect failed")
        backend.disconnect()
        logger.info(
            "%s disconnected after %d commands (commanded TCP path %.3f m); safety: %s.",
            self,
            self.commands_sent,
            self.commanded_path_m,
            self.safety.counters.as_dict(),
        )

    # -- safety helpers ---------------------------------------------------------------------------------------
    @property
    def safety_counters(self) -> dict[str, int]:
        """Clipped / rejected commands and watchdog stops since construction (for logs and tests)."""
        counters = self.safety.counters.as_dict()
        if self.watchdog is not None:
            counters["watchdog_stops"] += self.watchdog.trips
        return counters

    def recover(self) -> None:
        """Bring the arm back after a protective stop or a stopped control script (rtde backend).

        Unlocks the protective stop as soon as the controller allows it (5 s after it occurred), re-uploads
        ur_rtde's control script and returns once it runs; the next command starts from the measured pose.
        """
        if self.backend is None:
            raise RuntimeError(f"{self} is not connected; call connect() first.")
        recover = getattr(self.backend, "recover", None)
        if recover is None:
            raise RobotFaultError(f"{self}: the {self.config.backend} backend has nothing to recover; reconnect.")
        recover()
        self.watchdog.clear_fault()
        self._fault_reported = False
        self._target = None

    def _ensure_healthy(self) -> None:
        """Raise RobotFaultError (after stopping the arm) if the backend or the watchdog saw a fault."""
        try:
            self.watchdog.raise_if_faulted()
            self.backend.check_health()
        except RobotFaultError:
            self._on_fault()
            raise

    def _on_fault(self) -> None:
        """Stop the arm; when the controller is gone, also release the backend (its client, the watchdog)."""
        self._fault_reported = True
        self._stop_quietly()
        if self.backend is not None and not self.backend.is_connected:
            if self.watchdog is not None:
                self.watchdog.stop()
                self.safety.counters.watchdog_stops += self.watchdog.trips
                self.watchdog = None
            backend, self.backend = self.backend, None
            try:
                backend.disconnect()
            except Exception:  # noqa: BLE001 - already reporting the fault
                logger.exception("Releasing the lost UR10e backend failed")

    def _stop_quietly(self) -> None:
        self._target = None
        try:
            self.backend.stop()
        except Exception:  # noqa: BLE001 - already reporting a fault; the stop is best effort
            logger.exception("UR10e stop failed")

    # -- observation ------------------------------------------------------------------------------------------
    @check_if_not_connected
    def get_observation(self) -> RobotObservation:
        self._ensure_healthy()
        state = self.backend.read_state()
        obs: dict[str, Any] = {f"{j}.pos": float(v) for j, v in zip(JOINT_NAMES, state.q, strict=True)}
        obs.update({k: float(v) for k, v in zip(TCP_KEYS, state.tcp_pose, strict=True)})
        obs[GRIPPER_KEY] = float(state.gripper_opening_m / AG95_MAX_OPENING_M)
        for name, (rgb, depth) in self.backend.read_cameras().items():
            if rgb is not None:
                obs[name] = rgb
            if depth is not None:
                obs[f"{name}_depth"] = depth
        return obs

    def camera_infos(self) -> dict[str, CameraInfo]:
        """Intrinsics + base-frame extrinsics of each depth camera (needed to unproject stored depth)."""
        if self.backend is None:
            raise RuntimeError(f"{self} is not connected: camera intrinsics are read from the running camera.")
        return self.backend.camera_infos()

    # -- action -----------------------------------------------------------------------------------------------
    def _refuse(self, message: str) -> UnsafeActionError:
        """Count a refused action and stop the arm: a caller that sends garbage must not leave it moving."""
        self.safety.counters.rejected_actions += 1
        self._stop_quietly()
        return UnsafeActionError(message)

    def _number(self, key: str, value: Any) -> float:
        """`value` as a float if it is one number (Python/numpy/torch scalar or a one-element array)."""
        if isinstance(value, (str, bytes)) or value is None:
            raise self._refuse(f"UR10e action {key!r} must be a number, got {type(value).__name__} {value!r}.")
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise self._refuse(
                f"UR10e action {key!r} must be a number, got {type(value).__name__} {value!r}."
            ) from None
        if arr.size != 1:
            raise self._refuse(
                f"UR10e action {key!r} must be one number, got an array of shape {arr.shape}; send one value per "
                f"key ({', '.join(self.action_features)})."
            )
        return float(arr.reshape(-1)[0])

    def _parse(self, action: RobotAction) -> tuple[str, np.ndarray, float | None]:
        known = (*VELOCITY_KEYS, *ABSOLUTE_KEYS, GRIPPER_KEY)
        if not any(k in action for k in known):
            raise self._refuse(
                f"UR10e action has none of the robot's keys (got {sorted(map(str, action))}); send "
                f"{list(self.action_features)} (velocity mode) or {list(ABSOLUTE_KEYS)} (absolute targets)."
            )
        values = {k: self._number(k, v) for k, v in action.items() if k in known}
        try:
            self.safety.check_finite(values)
        except UnsafeActionError:
            self._stop_quietly()
            raise
        has_abs = any(k in values for k in ABSOLUTE_KEYS)
        has_vel = any(k in values for k in VELOCITY_KEYS)
        if has_abs and has_vel:
            raise self._refuse(
                "UR10e action mixes absolute (ee_x.pos ...) and velocity (ee_x.vel ...) keys; send one kind."
            )
        gripper = values.get(GRIPPER_KEY)
        if has_abs:
            missing = [k for k in ABSOLUTE_KEYS if k not in values]
            if missing:
                raise self._refuse(f"UR10e absolute action is missing {missing}; send all of {list(ABSOLUTE_KEYS)}.")
            return "absolute", np.array([values[k] for k in ABSOLUTE_KEYS]), gripper
        dt = 1.0 / self.config.control_hz
        return "delta", np.array([values.get(k, 0.0) * dt for k in VELOCITY_KEYS]), gripper

    def _reference_pose(self, measured: np.ndarray) -> np.ndarray:
        """Pose that deltas and the step limit are relative to: the last commanded target while tracking.

        Composing with the last target (not the measured pose) keeps tracking lag from accumulating into drift;
        after a stop, a watchdog trip or a large tracking error (a collision) it re-anchors on the measured pose.
        """
        target = self._target
        if target is None or self.watchdog.tripped:
            return measured
        dpos, drot = pose_difference(target, measured)
        if np.linalg.norm(dpos) > _REANCHOR_M or np.linalg.norm(drot) > _REANCHOR_RAD:
            return measured
        return target

    @check_if_not_connected
    def send_action(self, action: RobotAction) -> RobotAction:
        self._ensure_healthy()
        mode, vec, gripper = self._parse(action)
        current = self._reference_pose(self.backend.read_state().tcp_pose)
        target = apply_delta(current, vec) if mode == "delta" else vec
        safe = self.safety.limit(target, current)
        self._target = safe
        self.commands_sent += 1
        self.commanded_path_m += float(np.linalg.norm(safe[:3] - current[:3]))
        try:
            self.backend.servo_tcp(safe)
            if gripper is not None:
                self._gripper_cmd = float(np.clip(gripper, 0.0, 1.0))
                if self._gripper_cmd != gripper:
                    self.safety.counters.gripper_clips += 1
                    logger.warning("gripper.pos %s outside [0, 1] (opening fraction), clipped to %s", gripper,
                                   self._gripper_cmd)
                self.backend.set_gripper(self._gripper_cmd * AG95_MAX_OPENING_M)
        except RobotFaultError:
            self._on_fault()
            raise
        self.watchdog.kick()

        sent: dict[str, float] = {}
        if mode == "delta":
            p_s, r_s = matrix_from_pose6(safe)
            p_c, r_c = matrix_from_pose6(current)
            rot = (Rotation.from_matrix(r_s) * Rotation.from_matrix(r_c).inv()).as_euler("xyz")
            sent.update(zip(VELOCITY_KEYS, np.array([*(p_s - p_c), *rot]) * self.config.control_hz, strict=True))
        else:
            sent.update(zip(ABSOLUTE_KEYS, safe, strict=True))
        sent = {k: float(v) for k, v in sent.items()}
        if self._gripper_cmd is not None:
            sent[GRIPPER_KEY] = self._gripper_cmd
        return sent
