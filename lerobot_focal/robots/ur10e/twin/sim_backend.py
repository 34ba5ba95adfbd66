"""MuJoCo twin of the UR-10e work cell, running in real time on a background thread.

It behaves like the real arm as seen from the driver: a TCP target is tracked until the next one arrives (like
servoL), the arm keeps moving between commands, `stop()` holds the current pose, and faults can be injected so
the fault paths of the driver are testable without hardware. Cartesian targets are turned into joint targets
by damped-least-squares IK on the same MuJoCo model, at the command rate. The camera renders the pose of the
instant it is read, or, with ``sim_camera_fps`` > 0, in its own thread whose latest frame each read takes (what
LeRobot's camera threads do on the real arm).
"""

from __future__ import annotations

import logging
import threading
import time

import mujoco
import numpy as np

from ..backend import ArmState
from ..camera_info import CameraInfo
from ..config_ur10e import UR10eConfig
from ..kinematics import HOME_Q, JOINT_LIMITS, JOINT_MAX_SPEED, JOINT_NAMES, matrix_from_pose6, pose6_from_matrix
from ..safety import RobotFaultError
from .scene import SceneSpec, build_scene_xml
from .sim_camera import RayCastCamera

logger = logging.getLogger(__name__)

_HOME_Q = np.array(HOME_Q)


class DampedLeastSquaresIK:
    """Position + orientation IK for the TCP site on a private MjData (never the simulated one)."""

    def __init__(self, model: mujoco.MjModel, site: str = "tcp", damping: float = 0.05, iters: int = 15):
        self.model = model
        self.data = mujoco.MjData(model)
        self.site_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site)
        self.damping = damping
        self.iters = iters
        self.dofs = np.arange(6)
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._lo = np.array([lim[0] for lim in JOINT_LIMITS])
        self._hi = np.array([lim[1] for lim in JOINT_LIMITS])

    def solve(self, q_init: np.ndarray, pos: np.ndarray, rot: np.ndarray, tol: float = 1e-5) -> np.ndarray:
        d = self.data
        q = np.array(q_init, dtype=np.float64)
        lam2 = self.damping**2
        for _ in range(self.iters):
            d.qpos[:6] = q
            mujoco.mj_kinematics(self.model, d)
            mujoco.mj_comPos(self.model, d)
            cur_p = d.site_xpos[self.site_id]
            cur_r = d.site_xmat[self.site_id].reshape(3, 3)
            err_p = pos - cur_p
            r_err = rot @ cur_r.T
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, r_err.reshape(-1))
            err_r = np.zeros(3)
            mujoco.mju_quat2Vel(err_r, quat, 1.0)
            err = np.concatenate([err_p, err_r])
            if np.linalg.norm(err) < tol:
                break
            mujoco.mj_jacSite(self.model, d, self._jacp, self._jacr, self.site_id)
            jac = np.vstack([self._jacp[:, self.dofs], self._jacr[:, self.dofs]])
            dq = jac.T @ np.linalg.solve(jac @ jac.T + lam2 * np.eye(6), err)
            q = np.clip(q + dq, self._lo, self._hi)
        return q


class SimBackend:
    """ArmBackend for the MuJoCo twin (see module docstring)."""

    def __init__(self, config: UR10eConfig):
        self.config = config
        self.scene = SceneSpec(
            tcp_offset=config.tcp_offset,
            camera_pos=tuple(config.sim_camera_pos),
            camera_lookat=tuple(config.sim_camera_lookat),
            camera_fovy_deg=config.sim_camera_fovy_deg,
        )
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self._fault: str | None = None
        self._q_des = _HOME_Q.copy()
        self._q_set = _HOME_Q.copy()
        self._gripper_des = 0.0
        self.steps_per_second = 0.0
        self._render_lock = threading.Lock()  # the render data and camera are used by one thread at a time
        self._camera_thread: threading.Thread | None = None
        self._latest_frame: tuple[np.ndarray, np.ndarray] | None = None
        self._new_frame = threading.Event()

    # -- lifecycle --------------------------------------------------------------------------------------------
    @property
    def is_connected(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def connect(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(build_scene_xml(self.scene))
        self.data = mujoco.MjData(self.model)
        self._arm_qadr = np.array([self.model.jnt_qposadr[self.model.joint(n).id] for n in JOINT_NAMES])
        self._finger_qadr = np.array(
            [self.model.jnt_qposadr[self.model.joint(n).id] for n in ("left_finger", "right_finger")]
        )
        self._tcp_site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "tcp")
        self._ik = DampedLeastSquaresIK(self.model)
        self._render_data = mujoco.MjData(self.model)
        self._camera = RayCastCamera(
            self.model, self.config.sim_camera_name, self.config.sim_camera_width, self.config.sim_camera_height
        )
        self._max_joint_step = (
            np.array(JOINT_MAX_SPEED) * self.config.sim_joint_speed_fraction * self.model.opt.timestep
        )
        self.data.qpos[self._arm_qadr] = _HOME_Q
        self.data.ctrl[:6] = _HOME_Q
        self._gripper_des = 0.0
        self._q_des = _HOME_Q.copy()
        self._q_set = _HOME_Q.copy()
        mujoco.mj_forward(self.model, self.data)
        self._fault = None
        self._running.set()
        self._thread = threading.Thread(target=self._physics_loop, name="ur10e-sim", daemon=True)
        self._thread.start()
        self._latest_frame = None
        self._new_frame.clear()
        if self.config.sim_camera_fps > 0:
            self._camera_thread = threading.Thread(target=self._camera_loop, name="ur10e-sim-camera", daemon=True)
            self._camera_thread.start()

    def disconnect(self) -> None:
        self._running.clear()
        for thread in (self._thread, self._camera_thread):
            if thread is not None:
                thread.join(timeout=2.0)
        self._thread = self._camera_thread = None

    # -- physics ----------------------------------------------------------------------------------------------
    def _physics_loop(self) -> None:
        m, d = self.model, self.data
        dt = m.opt.timestep
        t_wall0 = time.perf_counter()
        t_sim0 = d.time
        window_t, window_steps = time.perf_counter(), 0
        try:
            while self._running.is_set():
                lag = (time.perf_counter() - t_wall0) - (d.time - t_sim0)
                n = min(int(lag / dt), 50)  # catch up in bounded bursts so a stall cannot freeze the loop
                if n <= 0:
                    time.sleep(min(dt, -lag) if lag < 0 else 0.0005)
                    continue
                with self._lock:
                    for _ in range(n):
                        self._q_set += np.clip(self._q_des - self._q_set, -self._max_joint_step, self._max_joint_step)
                        d.ctrl[:6] = self._q_set
                        d.ctrl[6:8] = self._gripper_des / 2
                        mujoco.mj_step(m, d)
                    if not np.all(np.isfinite(d.qacc)):
                        raise FloatingPointError("simulation diverged (non-finite accelerations)")
                window_steps += n
                now = time.perf_counter()
                if now - window_t > 1.0:
                    self.steps_per_second = window_steps / (now - window_t)
                    window_t, window_steps = now, 0
                if lag > 0.5:  # fell far behind (e.g. the host was busy): drop the backlog, keep real time
                    t_wall0 += lag
        except Exception as e:  # noqa: BLE001 - surfaced through check_health()
            self._fault = f"simulation thread crashed: {e!r}"
            logger.exception("UR10e sim physics thread crashed")

    # -- ArmBackend -------------------------------------------------------------------------------------------
    def read_state(self) -> ArmState:
        with self._lock:
            q = self.data.qpos[self._arm_qadr].copy()
            pos = self.data.site_xpos[self._tcp_site].copy()
            rot = self.data.site_xmat[self._tcp_site].reshape(3, 3).copy()
            opening = float(self.data.qpos[self._finger_qadr].sum())
        return ArmState(q=q, tcp_pose=pose6_from_matrix(pos, rot), gripper_opening_m=opening)

    def servo_tcp(self, pose6: np.ndarray) -> None:
        pos, rot = matrix_from_pose6(pose6)
        with self._lock:
            q_init = self._q_des.copy()
        q = self._ik.solve(q_init, pos, rot)
        with self._lock:
            self._q_des = q

    def servo_joints(self, q: np.ndarray) -> None:
        """Track these joint positions (the twin of servoJ / moveJ), clipped to the joint limits."""
        lo = np.array([lim[0] for lim in JOINT_LIMITS])
        hi = np.array([lim[1] for lim in JOINT_LIMITS])
        with self._lock:
            self._q_des = np.clip(np.asarray(q, dtype=np.float64), lo, hi)

    def set_gripper(self, opening_m: float) -> None:
        with self._lock:
            self._gripper_des = float(opening_m)

    def stop(self) -> None:
        """Hold the current joint positions (the twin of speedStop/servoStop)."""
        with self._lock:
            q = self.data.qpos[self._arm_qadr].copy()
            self._q_des = q
            self._q_set = q.copy()

    def check_health(self) -> None:
        if self._fault is not None:
            raise RobotFaultError(f"UR10e (sim): {self._fault}. Reconnect the robot to reset the simulation.")
        if not self.is_connected:
            raise RobotFaultError("UR10e (sim): the simulation is not running; call connect() first.")

    def inject_fault(self, reason: str) -> None:
        """Test hook: make the twin behave like an arm that lost its connection or hit a protective stop."""
        self._fault = reason

    def read_cameras(self) -> dict[str, tuple[np.ndarray | None, np.ndarray | None]]:
        if self._camera_thread is None:
            return {self.config.sim_camera_name: self._render()}
        if not self._new_frame.wait(timeout=5.0):
            raise RobotFaultError("UR10e (sim): the camera thread produced no frame within 5 s.")
        return {self.config.sim_camera_name: self._latest_frame}

    def _render(self) -> tuple[np.ndarray, np.ndarray]:
        """(rgb, depth) of the arm's pose at this instant."""
        with self._render_lock:
            rd = self._render_data
            with self._lock:
                rd.qpos[:] = self.data.qpos
            mujoco.mj_kinematics(self.model, rd)
            mujoco.mj_camlight(self.model, rd)
            return self._camera.render(rd)

    def _camera_loop(self) -> None:
        """Render at sim_camera_fps and keep the latest frame, as a real camera's driver thread does."""
        period = 1.0 / self.config.sim_camera_fps
        next_t = time.perf_counter()
        try:
            while self._running.is_set():
                self._latest_frame = self._render()  # replaced, never mutated: readers keep a consistent frame
                self._new_frame.set()
                next_t += period
                delay = next_t - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                else:  # rendering is slower than the frame rate: deliver as fast as it can, without bursts
                    next_t = time.perf_counter()
        except Exception as e:  # noqa: BLE001 - surfaced through check_health()
            self._fault = f"camera thread crashed: {e!r}"
            logger.exception("UR10e sim camera thread crashed")

    def camera_infos(self) -> dict[str, CameraInfo]:
        with self._render_lock:
            rd = self._render_data
            mujoco.mj_kinematics(self.model, rd)
            mujoco.mj_camlight(self.model, rd)
            return {self.config.sim_camera_name: self._camera.camera_info(rd)}

    def joint_velocities(self) -> np.ndarray:
        with self._lock:
            return self.data.qvel[[self.model.jnt_dofadr[self.model.joint(n).id] for n in JOINT_NAMES]].copy()
