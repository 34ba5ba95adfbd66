"""The register protocol of ur_rtde's uploaded control script, played by the emulated controller.

``RTDEControlInterface`` uploads a URScript program (``rtde_control``) and from then on talks to it only through
RTDE registers: the client writes a command id into ``input_int_register_0`` and its arguments into
``input_double_register_*`` (plus an async flag in an int register for moves); the script answers in
``output_int_register_0`` (1 = ready, 2 = command done), ``output_int_register_1`` (return values) and
``output_int_register_2`` (async progress). So an emulator never runs URScript: it plays this state machine and
moves the MuJoCo twin the way the script would move the arm.

* Real-time commands (servoL/servoJ/speedL/speedJ) are re-read every cycle while their id stays in the
  register: the state stays 1 and the client does not wait.
* Other commands run once: the state becomes 2 when done (moveL/moveJ: when the motion has finished, or at
  once when asynchronous), the client writes 0 (clear) and the state returns to 1.
* stopScript (255) ends the program.

Every command that reached the script is logged with its raw registers, so tests can assert what the real
client put on the wire (pose order and units, servo parameters, which stop call was used).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from lerobot_focal.robots.ur10e.kinematics import pose6_from_rotvec_pose, rotvec_pose_from_pose6

logger = logging.getLogger(__name__)

# Command ids of ur_rtde 1.6.5's script (input_int_register_0).
CMD_CLEAR = 0
CMD_MOVEJ = 1
CMD_MOVEL = 3
CMD_SPEEDJ = 9
CMD_SPEEDL = 10
CMD_SERVOJ = 11
CMD_SPEED_STOP = 15
CMD_SERVO_STOP = 16
CMD_SERVOL = 24
CMD_SET_TCP = 29
CMD_PROTECTIVE_STOP = 31
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_STOP_SCRIPT = 255
COMMAND_NAMES = {
    CMD_CLEAR: "clear", CMD_MOVEJ: "moveJ", CMD_MOVEL: "moveL", CMD_SPEEDJ: "speedJ", CMD_SPEEDL: "speedL",
    CMD_SERVOJ: "servoJ", CMD_SET_TCP: "setTcp", CMD_SPEED_STOP: "speedStop", CMD_SERVO_STOP: "servoStop",
    CMD_SERVOL: "servoL", CMD_PROTECTIVE_STOP: "triggerProtectiveStop", CMD_STOPL: "stopL", CMD_STOPJ: "stopJ",
    CMD_STOP_SCRIPT: "stopScript",
}  # fmt: skip
REALTIME_COMMANDS = frozenset({CMD_SPEEDJ, CMD_SPEEDL, CMD_SERVOJ, CMD_SERVOL})

STATE_READY = 1
STATE_DONE = 2

N_REGISTERS = 48


class TwinArm(Protocol):
    """What the script needs from the simulated arm (``SimBackend`` provides it)."""

    def read_state(self) -> Any: ...

    def servo_tcp(self, pose6: np.ndarray) -> None: ...

    def servo_joints(self, q: np.ndarray) -> None: ...

    def stop(self) -> None: ...


@dataclass
class CommandRecord:
    """One command as it reached the script: id, the recipe it came in, and its raw registers."""

    t: float
    command: int
    recipe: int
    ints: dict[int, int]
    doubles: dict[int, float]

    @property
    def name(self) -> str:
        return COMMAND_NAMES.get(self.command, f"command {self.command}")

    def as_dict(self) -> dict:
        return {"t": self.t, "command": self.command, "name": self.name, "recipe": self.recipe,
                "ints": dict(self.ints), "doubles": dict(self.doubles)}  # fmt: skip


@dataclass
class _Motion:
    """A motion the script carries out over time (moveL / moveJ / speedL / speedJ)."""

    kind: str
    target: np.ndarray  # moveL: UR pose; moveJ: q; speedL: twist; speedJ: qd
    speed: float = 0.0
    start: np.ndarray | None = None
    t0: float = field(default_factory=time.monotonic)
    duration: float = 0.0
    base: np.ndarray | None = None  # speedL/speedJ: where the integration started
    sync: bool = True


def _ur_pose_of(arm: TwinArm) -> np.ndarray:
    return np.asarray(rotvec_pose_from_pose6(arm.read_state().tcp_pose))


class ControlScript:
    """State machine of the ``rtde_control`` program (see module docstring). Thread-safe."""

    def __init__(self, arm: TwinArm, on_protective_stop: Callable[[], None] | None = None, log_size: int = 20000):
        self.arm = arm
        self.on_protective_stop = on_protective_stop  # triggerProtectiveStop is the controller's business
        self.out_int = [0] * N_REGISTERS
        self.out_double = [0.0] * N_REGISTERS
        self.running = False
        self.uploads = 0
        self.commands: deque[CommandRecord] = deque(maxlen=log_size)
        self.commands_total = 0
        self._in_int = [0] * N_REGISTERS
        self._in_double = [0.0] * N_REGISTERS
        self._motion: _Motion | None = None
        self._last_recipe = 0
        self._lock = threading.RLock()

    # -- program lifecycle ------------------------------------------------------------------------------------
    def start(self) -> None:
        """The program was uploaded and starts: clear the handshake and report ready."""
        with self._lock:
            self.uploads += 1
            self.running = True
            self._motion = None
            self.out_int = [0] * N_REGISTERS
            self.out_double = [0.0] * N_REGISTERS
            self.out_int[0] = STATE_READY

    def halt(self) -> None:
        """The program stops (stopScript, dashboard stop, a protective stop that ends it): the arm holds."""
        with self._lock:
            self.running = False
            self._motion = None
            self.out_int[0] = 0
        self.arm.stop()

    def abort_motion(self) -> None:
        with self._lock:
            self._motion = None

    # -- register input ---------------------------------------------------------------------------------------
    def write_registers(self, recipe_id: int, values: dict[str, Any], active: bool) -> None:
        """Store a client's input registers; when `active` (the program runs and may move), act on them."""
        with self._lock:
            ints: dict[int, int] = {}
            doubles: dict[int, float] = {}
            for name, v in values.items():
                if name.startswith("input_int_register_"):
                    i = int(name.rsplit("_", 1)[1])
                    self._in_int[i] = int(v)
                    ints[i] = int(v)
                elif name.startswith("input_double_register_"):
                    i = int(name.rsplit("_", 1)[1])
                    self._in_double[i] = float(v)
                    doubles[i] = float(v)
            if 0 not in ints:
                return
            cmd = ints[0]
            if cmd != CMD_CLEAR:
                self.commands.append(CommandRecord(time.monotonic(), cmd, recipe_id, ints, doubles))
                self.commands_total += 1
            if self.running and active:
                self._dispatch(cmd)

    def _dispatch(self, cmd: int) -> None:
        d = self._in_double
        if cmd == CMD_CLEAR:
            if self.out_int[0] == STATE_DONE:
                self.out_int[0] = STATE_READY
            return
        if cmd == CMD_STOP_SCRIPT:
            self.halt()
            return
        if cmd in REALTIME_COMMANDS:
            if cmd == CMD_SERVOL:
                self._motion = None
                self.arm.servo_tcp(pose6_from_rotvec_pose(d[0:6]))
            elif cmd == CMD_SERVOJ:
                self._motion = None
                self.arm.servo_joints(np.array(d[0:6]))
            elif cmd == CMD_SPEEDL:
                m = self._motion
                twist = np.array(d[0:6])
                if m is None or m.kind != "speedL":
                    self._motion = _Motion("speedL", twist, base=_ur_pose_of(self.arm))
                else:  # a new twist continues from where the integration has got to
                    m.base, m.t0, m.target = self._speed_target(m), time.monotonic(), twist
            elif cmd == CMD_SPEEDJ:
                self._motion = _Motion("speedJ", np.array(d[0:6]), base=np.asarray(self.arm.read_state().q))
            self.out_int[0] = STATE_READY
            return
        if self.out_int[0] != STATE_READY:
            return  # a run-once command is only taken when the script is ready (not while "done" is pending)
        if cmd in (CMD_SPEED_STOP, CMD_SERVO_STOP, CMD_STOPL, CMD_STOPJ):
            if cmd == CMD_SERVO_STOP and self._motion is not None and self._motion.kind in ("speedL", "speedJ"):
                pass  # servoStop does not end speed mode on a real controller: the arm keeps its velocity
            else:
                self._motion = None
                self.arm.stop()
            self.out_int[0] = STATE_DONE
        elif cmd == CMD_PROTECTIVE_STOP:
            self.out_int[0] = STATE_DONE
            if self.on_protective_stop is not None:
                self.on_protective_stop()
        elif cmd in (CMD_MOVEL, CMD_MOVEJ):
            sync = self._in_int[1] == 0
            start = _ur_pose_of(self.arm) if cmd == CMD_MOVEL else np.asarray(self.arm.read_state().q)
            target = np.array(d[0:6])
            speed = max(float(d[6]), 1e-3)
            self._motion = _Motion("moveL" if cmd == CMD_MOVEL else "moveJ", target, speed, start=start, sync=sync)
            self._motion.duration = float(np.linalg.norm((target - start)[:3 if cmd == CMD_MOVEL else 6])) / speed
            if not sync:
                self.out_int[0] = STATE_DONE
                self.out_int[2] = 1  # async operation in progress
        else:
            self.out_int[0] = STATE_DONE  # setTcp, setPayload, ...: accepted, nothing to move

    # -- motion over time -------------------------------------------------------------------------------------
    def _speed_target(self, m: _Motion) -> np.ndarray:
        t = time.monotonic() - m.t0
        if m.kind == "speedJ":
            return m.base + m.target * t
        pos = m.base[:3] + m.target[:3] * t
        rot = Rotation.from_rotvec(m.target[3:6] * t) * Rotation.from_rotvec(m.base[3:6])
        return np.concatenate([pos, rot.as_rotvec()])

    def tick(self) -> None:
        """Advance a moveL/moveJ/speedL/speedJ in progress (called periodically by the controller)."""
        with self._lock:
            m = self._motion
            if m is None or not self.running:
                return
            if m.kind in ("speedL", "speedJ"):
                target = self._speed_target(m)
                if m.kind == "speedL":
                    self.arm.servo_tcp(pose6_from_rotvec_pose(target))
                else:
                    self.arm.servo_joints(target)
                return
            frac = 1.0 if m.duration <= 0 else min(1.0, (time.monotonic() - m.t0) / m.duration)
            if m.kind == "moveL":
                pos = m.start[:3] + frac * (m.target[:3] - m.start[:3])
                r0, r1 = Rotation.from_rotvec(m.start[3:6]), Rotation.from_rotvec(m.target[3:6])
                rot = Rotation.from_rotvec((r1 * r0.inv()).as_rotvec() * frac) * r0
                self.arm.servo_tcp(pose6_from_rotvec_pose(np.concatenate([pos, rot.as_rotvec()])))
                err = np.linalg.norm(_ur_pose_of(self.arm)[:3] - m.target[:3])
            else:
                self.arm.servo_joints(m.start + frac * (m.target - m.start))
                err = float(np.abs(np.asarray(self.arm.read_state().q) - m.target).max())
            if frac >= 1.0 and err < 2e-3:
                self._motion = None
                if m.sync:
                    self.out_int[0] = STATE_DONE
                self.out_int[2] = 0

    # -- diagnostics ------------------------------------------------------------------------------------------
    def recent_commands(self, since: int = 0) -> list[dict]:
        """Commands logged after the first `since` ones (indices count from the start of the emulator)."""
        with self._lock:
            first = self.commands_total - len(self.commands)
            return [c.as_dict() for c in list(self.commands)[max(0, since - first) :]]
