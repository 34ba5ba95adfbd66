"""Safety limits every end-effector command passes through, whatever the backend.

Kept free of MuJoCo and RTDE so the same code guards the simulated twin and the real arm: what a policy
learns to send in simulation is limited exactly as it will be on hardware.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from .kinematics import matrix_from_pose6, pose6_from_matrix, pose_difference

logger = logging.getLogger(__name__)


class UnsafeActionError(ValueError):
    """An action that cannot be made safe by clipping (NaN / inf): motion has been stopped."""


class RobotFaultError(RuntimeError):
    """The arm is not able to move: connection lost, protective stop, emergency stop or watchdog fault."""


@dataclass
class SafetyConfig:
    """Limits applied to every command (base frame, metres / radians)."""

    # Axis-aligned box the TCP target must stay inside; the default covers the table in front of the robot.
    workspace_min: tuple[float, float, float] = (-1.05, -0.65, 0.015)
    workspace_max: tuple[float, float, float] = (-0.3, 0.35, 0.75)
    # Speed limits, turned into a per-command step limit with the nominal control period.
    max_linear_speed: float = 0.25
    max_angular_speed: float = 1.0
    # Stop the arm when no command arrived for this long (seconds); <= 0 disables the watchdog.
    watchdog_timeout_s: float = 0.5


@dataclass
class SafetyCounters:
    workspace_clips: int = 0
    step_clips: int = 0
    watchdog_stops: int = 0
    rejected_actions: int = 0
    gripper_clips: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class SafetyFilter:
    """Turns a requested TCP target into one that is finite, within one step of the current pose and in the box.

    Order matters: the step limit is applied before the box so that a clipped target is still reachable in one
    control period, and the box is applied last so nothing outside it is ever sent, whatever the step limit did.
    """

    config: SafetyConfig
    control_hz: float
    counters: SafetyCounters = field(default_factory=SafetyCounters)

    def check_finite(self, values: dict[str, float] | np.ndarray, what: str = "action") -> None:
        arr = np.asarray(list(values.values()) if isinstance(values, dict) else values, dtype=np.float64)
        if not np.all(np.isfinite(arr)):
            self.counters.rejected_actions += 1
            bad = (
                [k for k, v in values.items() if not np.isfinite(v)]
                if isinstance(values, dict)
                else np.flatnonzero(~np.isfinite(arr)).tolist()
            )
            raise UnsafeActionError(
                f"Refusing {what} with non-finite values in {bad}: the arm has been stopped. "
                "Check the policy output / teleoperator for NaN or inf (e.g. an unnormalised or diverged model)."
            )

    def limit(self, target: np.ndarray, current: np.ndarray) -> np.ndarray:
        """Return the safe pose6 target for `target` given the measured `current` TCP pose6."""
        target = np.asarray(target, dtype=np.float64).copy()
        self.check_finite(target, "TCP target")
        dpos, drot = pose_difference(target, current)
        max_step = self.config.max_linear_speed / self.control_hz
        max_rot = self.config.max_angular_speed / self.control_hz
        step = np.linalg.norm(dpos)
        angle = np.linalg.norm(drot)
        if step > max_step + 1e-12 or angle > max_rot + 1e-12:
            self.counters.step_clips += 1
            if step > max_step:
                dpos = dpos * (max_step / step)
            if angle > max_rot:
                drot = drot * (max_rot / angle)
            pos_c, rot_c = matrix_from_pose6(current)
            rot = Rotation.from_rotvec(drot) * Rotation.from_matrix(rot_c)
            target = pose6_from_matrix(pos_c + dpos, rot.as_matrix())
        lo = np.asarray(self.config.workspace_min, dtype=np.float64)
        hi = np.asarray(self.config.workspace_max, dtype=np.float64)
        clipped = np.clip(target[:3], lo, hi)
        if np.any(clipped != target[:3]):
            self.counters.workspace_clips += 1
            logger.warning("TCP target %s outside the workspace box, clipped to %s", target[:3], clipped)
            target[:3] = clipped
        return target


class Watchdog:
    """Calls `on_timeout` once when `kick()` has not been called for `timeout_s`; re-armed by the next kick.

    It also runs `health_check` every period so a protective stop or a dropped connection is noticed even while
    no command is being sent; the first exception it raises is kept and re-raised by :meth:`raise_if_faulted`
    (from the caller's thread, where it can reach the user).
    """

    def __init__(
        self,
        timeout_s: float,
        on_timeout: Callable[[], None],
        health_check: Callable[[], None] | None = None,
        period_s: float = 0.02,
    ):
        self.timeout_s = timeout_s
        self.on_timeout = on_timeout
        self.health_check = health_check
        self.period_s = period_s
        self._last_kick: float | None = None
        self._tripped = False
        self._fault: BaseException | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.trips = 0

    @property
    def tripped(self) -> bool:
        return self._tripped

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="ur10e-watchdog", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None

    def kick(self) -> None:
        self._last_kick = time.monotonic()
        self._tripped = False

    def clear_fault(self) -> None:
        """Forget a reported fault (after the caller recovered the arm) so health checks resume."""
        self._fault = None
        self._tripped = False

    def raise_if_faulted(self) -> None:
        if self._fault is not None:
            raise RobotFaultError(str(self._fault)) from self._fault

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            if self.health_check is not None and self._fault is None:
                try:
                    self.health_check()
                except Exception as e:  # noqa: BLE001 - any failure means the arm must stop
                    self._fault = e
                    self._fire("fault: " + str(e))
            last = self._last_kick
            if (
                self.timeout_s > 0
                and last is not None
                and not self._tripped
                and time.monotonic() - last > self.timeout_s
            ):
                self.trips += 1
                self._fire(f"no command for more than {self.timeout_s:.3f} s")

    def _fire(self, reason: str) -> None:
        self._tripped = True
        logger.warning("UR10e watchdog stopping the arm: %s", reason)
        try:
            self.on_timeout()
        except Exception:  # noqa: BLE001 - stopping must not kill the watchdog
            logger.exception("UR10e watchdog failed to stop the arm")
