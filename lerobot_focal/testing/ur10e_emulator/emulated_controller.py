"""The state of an emulated UR controller: robot / safety / runtime state, the control script, the twin.

The RTDE, dashboard and script-port servers are thin I/O around this object; everything a controller decides
(what the RTDE outputs say, what the dashboard answers, when a protective stop may be unlocked, whether the
program pauses or stops on a protective stop) lives here, in one place, with the MuJoCo twin behind it.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

from lerobot_focal.robots.ur10e.kinematics import rotvec_pose_from_pose6

from .control_script import ControlScript, TwinArm

logger = logging.getLogger(__name__)

ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL = 1
SAFETY_MODE_PROTECTIVE_STOP = 3
SAFETY_BITS_NORMAL = 0x1
SAFETY_BITS_PROTECTIVE_STOP = 0x404  # "protective stopped" + "stopped due to safety"
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2
RUNTIME_PAUSED = 4
STATUS_BIT_POWER_ON = 1 << 0
STATUS_BIT_PROGRAM_RUNNING = 1 << 1
UNLOCK_DELAY_S = 5.0  # a protective stop cannot be unlocked earlier than this after it occurred
PROTECTIVE_STOP_POLICIES = ("pause", "stop")


@dataclass
class ControllerOptions:
    """How the emulated controller presents itself and behaves where real controllers differ."""

    version: tuple[int, int, int, int] = (5, 15, 0, 0)
    # What the program does on a protective stop: "pause" (runtime_state 4) or "stop" (1). UR's documentation
    # and ur_rtde's sources do not settle which a given controller does, so both are testable.
    on_protective_stop: str = "pause"
    serial_number: str = "20235500001"

    def __post_init__(self) -> None:
        self.version = tuple(int(v) for v in self.version)  # type: ignore[assignment]
        if self.on_protective_stop not in PROTECTIVE_STOP_POLICIES:
            raise ValueError(f"on_protective_stop must be one of {PROTECTIVE_STOP_POLICIES}")


class EmulatedController:
    """See module docstring. Call :meth:`start` to run the script's motion ticks; :meth:`stop` to end them."""

    def __init__(self, arm: TwinArm, options: ControllerOptions | None = None):
        self.arm = arm
        self.options = options or ControllerOptions()
        self.script = ControlScript(arm, on_protective_stop=lambda: self.protective_stop("triggerProtectiveStop"))
        self.runtime_state = RUNTIME_STOPPED
        self.protective_stop_since: float | None = None
        self.protective_stop_cause = ""
        self.dashboard_log: list[tuple[str, str]] = []  # (request, reply)
        self.script_uploads: list[str] = []  # first line of each uploaded program
        self.stall_until = 0.0  # network blip: no RTDE traffic in either direction until then
        self._lock = threading.RLock()
        self._running = threading.Event()
        self._t0 = time.monotonic()

    @property
    def version(self) -> tuple[int, int, int, int]:
        return self.options.version  # type: ignore[return-value]

    # -- lifecycle --------------------------------------------------------------------------------------------
    def start(self) -> EmulatedController:
        self._running.set()
        threading.Thread(target=self._tick_loop, name="ur-controller-tick", daemon=True).start()
        return self

    def stop(self) -> None:
        self._running.clear()

    def _tick_loop(self, period_s: float = 0.008) -> None:
        while self._running.is_set():
            try:
                if self.motion_allowed:
                    self.script.tick()
            except Exception:  # noqa: BLE001 - a bad tick must not end the controller
                logger.exception("controller tick failed")
            time.sleep(period_s)

    # -- state ------------------------------------------------------------------------------------------------
    @property
    def protective_stopped(self) -> bool:
        return self.protective_stop_since is not None

    @property
    def program_running(self) -> bool:
        return self.runtime_state == RUNTIME_PLAYING

    @property
    def motion_allowed(self) -> bool:
        return self.program_running and not self.protective_stopped

    def stalled(self) -> bool:
        return time.monotonic() < self.stall_until

    def outputs(self) -> dict[str, Any]:
        """Values of the RTDE output variables now."""
        state = self.arm.read_state()
        qd = self.arm.joint_velocities()
        tcp = rotvec_pose_from_pose6(state.tcp_pose)
        with self._lock:  # one consistent picture: safety bits and runtime state change together
            stopped = self.protective_stopped
            runtime_state = self.runtime_state
            out_int = list(self.script.out_int)
            out_double = list(self.script.out_double)
        values: dict[str, Any] = {
            "timestamp": time.monotonic() - self._t0,
            "actual_q": [float(x) for x in state.q],
            "target_q": [float(x) for x in state.q],
            "actual_qd": [float(x) for x in qd],
            "target_qd": [float(x) for x in qd],
            "actual_TCP_pose": [float(x) for x in tcp],
            "target_TCP_pose": [float(x) for x in tcp],
            "robot_mode": ROBOT_MODE_RUNNING,
            "joint_mode": [253] * 6,  # JOINT_RUNNING_MODE
            "safety_mode": SAFETY_MODE_PROTECTIVE_STOP if stopped else SAFETY_MODE_NORMAL,
            "safety_status": SAFETY_MODE_PROTECTIVE_STOP if stopped else SAFETY_MODE_NORMAL,
            "safety_status_bits": SAFETY_BITS_PROTECTIVE_STOP if stopped else SAFETY_BITS_NORMAL,
            "robot_status_bits": STATUS_BIT_POWER_ON
            | (STATUS_BIT_PROGRAM_RUNNING if runtime_state == RUNTIME_PLAYING else 0),
            "runtime_state": runtime_state,
            "speed_scaling": 1.0,
            "target_speed_fraction": 1.0,
            "actual_main_voltage": 48.0,
            "actual_robot_voltage": 48.0,
            "joint_temperatures": [30.0] * 6,
        }
        for i, (vi, vd) in enumerate(zip(out_int, out_double, strict=True)):
            values[f"output_int_register_{i}"] = vi
            values[f"output_double_register_{i}"] = vd
        return values

    # -- events -----------------------------------------------------------------------------------------------
    def on_registers(self, recipe_id: int, values: dict[str, Any]) -> None:
        """Input registers written by the RTDE client that owns them (the control interface)."""
        with self._lock:
            was_running = self.script.running
            self.script.write_registers(recipe_id, values, active=self.motion_allowed)
            if was_running and not self.script.running:
                self.runtime_state = RUNTIME_STOPPED

    def upload_script(self, program: str) -> None:
        with self._lock:
            self.script_uploads.append(program.lstrip().split("\n", 1)[0][:80])
            if self.protective_stopped:
                logger.info("script upload ignored: protective stop")
                return
            self.script.start()
            self.runtime_state = RUNTIME_PLAYING

    def protective_stop(self, cause: str = "protective stop") -> None:
        with self._lock:
            if self.protective_stopped:
                return
            self.protective_stop_since = time.monotonic()
            self.protective_stop_cause = cause
            self.script.abort_motion()
            self.arm.stop()
            if self.runtime_state == RUNTIME_PLAYING:
                if self.options.on_protective_stop == "pause":
                    self.runtime_state = RUNTIME_PAUSED
                else:
                    self.script.halt()
                    self.runtime_state = RUNTIME_STOPPED

    def stall(self, seconds: float) -> None:
        """A network blip: no RTDE traffic for `seconds` (TCP connections stay up)."""
        self.stall_until = time.monotonic() + float(seconds)

    # -- dashboard --------------------------------------------------------------------------------------------
    def dashboard(self, request: str) -> str:
        """Reply (without the newline) of the dashboard server to one request line."""
        with self._lock:
            reply = self._dashboard(request.strip())
            self.dashboard_log.append((request.strip(), reply))
            return reply

    def _dashboard(self, req: str) -> str:
        v = self.version
        low = req.lower()
        if req == "PolyscopeVersion":
            return f"URSoftware {v[0]}.{v[1]}.{v[2]}.{v[3]} (emulated)"
        if low == "get serial number":
            return self.options.serial_number
        if low == "is in remote control":
            return "true"
        if low == "robotmode":
            return "Robotmode: RUNNING"
        if low in ("safetystatus", "safetymode"):
            name = "PROTECTIVE_STOP" if self.protective_stopped else "NORMAL"
            return f"Safety{'status' if low == 'safetystatus' else 'mode'}: {name}"
        if low == "running":
            return f"Program running: {str(self.program_running).lower()}"
        if low == "programstate":
            names = {RUNTIME_PLAYING: "PLAYING", RUNTIME_PAUSED: "PAUSED", RUNTIME_STOPPED: "STOPPED"}
            return f"{names.get(self.runtime_state, 'STOPPED')} rtde_control"
        if low == "stop":
            # A stopped program stays stopped; ur_rtde sends this right after its own stopScript ended the
            # script and expects "Stopped" either way.
            if self.runtime_state in (RUNTIME_PLAYING, RUNTIME_PAUSED):
                self.script.halt()
                self.runtime_state = RUNTIME_STOPPED
            return "Stopped"
        if low == "play":
            if self.runtime_state == RUNTIME_PAUSED and not self.protective_stopped:
                self.runtime_state = RUNTIME_PLAYING
                return "Starting program"
            return "Failed to execute: play"
        if low == "unlock protective stop":
            if not self.protective_stopped:
                return "Cannot unlock protective stop, robot is not in protective stop"
            if time.monotonic() - self.protective_stop_since < UNLOCK_DELAY_S:
                return ("Cannot unlock protective stop until 5s after occurrence. Always inspect cause of "
                        "protective stop before unlocking")  # fmt: skip
            self.protective_stop_since = None
            self.protective_stop_cause = ""
            return "Protective stop releasing"
        if low.startswith("popup"):
            return "showing popup"
        if low == "close popup":
            return "closing popup"
        if low == "close safety popup":
            return "closing safety popup"
        if low == "power on":
            return "Powering on"
        if low == "brake release":
            return "Brake releasing"
        if low == "quit":
            return "Disconnected"
        return f"could not understand: '{req}'"
