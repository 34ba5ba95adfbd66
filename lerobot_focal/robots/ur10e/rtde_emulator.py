"""A UR controller's RTDE server (port 30004 protocol, version 2) on loopback, backed by the MuJoCo twin.

It lets the ``rtde`` backend and ``ur_rtde``'s *real* ``RTDEReceiveInterface`` run without an arm: the client
negotiates the protocol, asks for the controller version, sets up an output recipe by variable names, starts
synchronisation and then receives ``DATA_PACKAGE`` frames at the requested frequency, filled from the simulated
arm (joint positions and speeds, TCP pose as a UR rotation-vector pose, robot / safety mode and status bits).
Input recipes and input data packages are accepted and stored, so a client that writes registers works too.

What it does not do, and why ``ur_rtde``'s ``RTDEControlInterface`` cannot be served by it: that interface
connects to the dashboard server (29999) to check and (re)start programs, uploads a URScript program
(``rtde_control.script``) through the primary/secondary client interface (30001-30003) and then commands the
arm only through a register handshake with that *running script* (command ids and arguments in
``input_int_register_*`` / ``input_double_register_*``, status and acknowledgements in ``output_int_register_*``).
Serving it means executing URScript — a controller, not a protocol. The driver's control boundary is therefore
tested with :class:`FakeRTDEControlInterface` (a fake, named as such) that applies ``servoL`` to the same twin.

``ur_rtde``'s Python bindings keep the GIL while they block on the socket (e.g. in the
``RTDEReceiveInterface`` constructor), so a client in the same Python process would deadlock an in-process
server: :class:`RtdeEmulatorProcess` runs the server and the twin in a child process and exposes the fault
hooks over a pipe.

Run it standalone (then ``--robot.backend=rtde --robot.robot_ip=127.0.0.1`` reads the twin through ur_rtde)::

    python -m lerobot_focal.robots.ur10e.rtde_emulator --port 30004
"""

from __future__ import annotations

import logging
import re
import socket
import struct
import threading
import time
from typing import Any

import numpy as np


from .kinematics import pose6_from_rotvec_pose, rotvec_pose_from_pose6

logger = logging.getLogger(__name__)

# RTDE package types (ASCII codes), protocol version 2.
RTDE_REQUEST_PROTOCOL_VERSION = ord("V")
RTDE_GET_URCONTROL_VERSION = ord("v")
RTDE_TEXT_MESSAGE = ord("M")
RTDE_DATA_PACKAGE = ord("U")
RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
RTDE_CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
RTDE_CONTROL_PACKAGE_START = ord("S")
RTDE_CONTROL_PACKAGE_PAUSE = ord("P")

# RTDE type name -> struct format (network byte order).
_TYPE_FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}

# Output variables of a UR e-Series controller (RTDE guide), by type.
_OUTPUT_TYPES: dict[str, str] = {
    **dict.fromkeys(
        [
            "timestamp", "actual_execution_time", "speed_scaling", "target_speed_fraction", "actual_momentum",
            "actual_main_voltage", "actual_robot_voltage", "actual_robot_current", "standard_analog_input0",
            "standard_analog_input1", "standard_analog_output0", "standard_analog_output1", "io_current",
            "tool_analog_input0", "tool_analog_input1", "tool_output_current", "tool_temperature",
            "tcp_force_scalar", "payload", "joint_position_deviation_ratio", "collision_detection_ratio",
            "actual_robot_energy_consumed", "actual_robot_braking_energy_dissipated",
        ],
        "DOUBLE",
    ),
    **dict.fromkeys(
        [
            "target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q", "actual_qd",
            "actual_current", "actual_current_window", "joint_control_output", "actual_TCP_pose",
            "actual_TCP_speed", "actual_TCP_force", "target_TCP_pose", "target_TCP_speed", "joint_temperatures",
            "actual_joint_voltage", "payload_inertia", "ft_raw_wrench", "actual_current_as_torque",
        ],
        "VECTOR6D",
    ),
    **dict.fromkeys(
        ["actual_tool_accelerometer", "elbow_position", "elbow_velocity", "payload_cog"], "VECTOR3D"
    ),
    **dict.fromkeys(["actual_digital_input_bits", "actual_digital_output_bits"], "UINT64"),
    **dict.fromkeys(
        [
            "runtime_state", "robot_status_bits", "safety_status_bits", "analog_io_types", "tool_mode",
            "tool_analog_input_types", "output_bit_registers0_to_31", "output_bit_registers32_to_63",
            "input_bit_registers0_to_31", "input_bit_registers32_to_63", "script_control_line",
        ],
        "UINT32",
    ),
    **dict.fromkeys(["robot_mode", "safety_mode", "safety_status", "tool_output_voltage"], "INT32"),
    "joint_mode": "VECTOR6INT32",
    **dict.fromkeys(["tool_output_mode", "tool_digital_output0_mode", "tool_digital_output1_mode"], "UINT8"),
}

# Input variables (what a client may write), by type.
_INPUT_TYPES: dict[str, str] = {
    **dict.fromkeys(
        [
            "speed_slider_mask", "standard_digital_output_mask", "standard_digital_output",
            "configurable_digital_output_mask", "configurable_digital_output", "tool_digital_output_mask",
            "tool_digital_output", "standard_analog_output_mask", "standard_analog_output_type",
            "input_bit_registers0_to_31", "input_bit_registers32_to_63",
        ],
        "UINT32",
    ),
    **dict.fromkeys(["speed_slider_fraction", "standard_analog_output_0", "standard_analog_output_1"], "DOUBLE"),
}
_REGISTER = re.compile(r"^(input|output)_(int|double|bit)_register_(\d+)$")

# Values a healthy, running e-Series arm reports.
ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL = 1
SAFETY_MODE_PROTECTIVE_STOP = 3
_STATUS_BIT_NORMAL = 1 << 0
_STATUS_BIT_PROTECTIVE_STOPPED = 1 << 2
_RUNTIME_PLAYING = 2


def _variable_type(name: str, inputs: bool) -> str:
    m = _REGISTER.match(name)
    if m:
        direction, kind, index = m.group(1), m.group(2), int(m.group(3))
        if kind == "bit":
            return "BOOL" if 64 <= index <= 127 else "NOT_FOUND"
        if index > 47 or (inputs and direction != "input"):
            return "NOT_FOUND"
        return "INT32" if kind == "int" else "DOUBLE"
    table = _INPUT_TYPES if inputs else _OUTPUT_TYPES
    return table.get(name, "NOT_FOUND")


class _Recipe:
    def __init__(self, recipe_id: int, names: list[str], types: list[str]):
        self.id, self.names, self.types = recipe_id, names, types
        self.fmt = ">" + "".join(_TYPE_FORMATS.get(t, "") for t in types)


class RtdeEmulator:
    """RTDE server on ``host:port`` serving the state of ``arm`` (a connected ``SimBackend``); see module doc.

    ``port=0`` picks a free port (read :attr:`port` after :meth:`start`). Fault hooks for tests:
    :meth:`protective_stop` (the controller reports a protective stop and holds the arm) and
    :meth:`drop_connections` (every client socket is closed, like a pulled network cable).
    """

    def __init__(self, arm: Any, host: str = "127.0.0.1", port: int = 0, controller_version=(5, 15, 0, 0)):
        self.arm = arm
        self.host = host
        self.controller_version = tuple(int(v) for v in controller_version)
        self._requested_port = port
        self._server: socket.socket | None = None
        self._clients: list[socket.socket] = []
        self._lock = threading.Lock()
        self._running = threading.Event()
        self._protective_stop = threading.Event()
        self.requested_outputs: list[str] = []  # what clients asked for (diagnostics, tests)
        self.inputs: dict[str, Any] = {}  # last value written to each input variable
        self.packages_sent = 0

    # -- lifecycle --------------------------------------------------------------------------------------------
    @property
    def port(self) -> int:
        if self._server is None:
            raise RuntimeError("RtdeEmulator is not started")
        return self._server.getsockname()[1]

    def start(self) -> RtdeEmulator:
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind((self.host, self._requested_port))
        server.listen(4)
        server.settimeout(0.2)
        self._server = server
        self._running.set()
        threading.Thread(target=self._accept_loop, name="rtde-emulator", daemon=True).start()
        return self

    def stop(self) -> None:
        self._running.clear()
        self.drop_connections()
        if self._server is not None:
            self._server.close()

    def __enter__(self) -> RtdeEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- fault injection --------------------------------------------------------------------------------------
    def protective_stop(self) -> None:
        self._protective_stop.set()
        self.arm.stop()

    def drop_connections(self) -> None:
        with self._lock:
            clients, self._clients = self._clients, []
        for conn in clients:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            conn.close()

    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._clients)

    # -- protocol ---------------------------------------------------------------------------------------------
    def _accept_loop(self) -> None:
        while self._running.is_set():
            try:
                conn, _ = self._server.accept()
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                break
            conn.settimeout(None)  # accept() may hand down the listening socket's timeout
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._clients.append(conn)
            threading.Thread(target=self._serve, args=(conn,), name="rtde-emulator-client", daemon=True).start()

    @staticmethod
    def _recv_exact(conn: socket.socket, n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = conn.recv(n - len(buf))
            if not chunk:
                raise ConnectionError("client closed the connection")
            buf += chunk
        return buf

    @staticmethod
    def _send(conn: socket.socket, ptype: int, payload: bytes, lock: threading.Lock) -> None:
        with lock:
            conn.sendall(struct.pack(">HB", 3 + len(payload), ptype) + payload)

    def _serve(self, conn: socket.socket) -> None:
        send_lock = threading.Lock()
        outputs: _Recipe | None = None
        inputs: dict[int, _Recipe] = {}
        frequency = 125.0
        streaming = threading.Event()
        try:
            while self._running.is_set():
                size, ptype = struct.unpack(">HB", self._recv_exact(conn, 3))
                payload = self._recv_exact(conn, size - 3)
                if ptype == RTDE_REQUEST_PROTOCOL_VERSION:
                    (version,) = struct.unpack(">H", payload)
                    self._send(conn, ptype, struct.pack(">B", int(version in (1, 2))), send_lock)
                elif ptype == RTDE_GET_URCONTROL_VERSION:
                    self._send(conn, ptype, struct.pack(">IIII", *self.controller_version), send_lock)
                elif ptype == RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS:
                    (frequency,) = struct.unpack(">d", payload[:8])
                    names = [n for n in payload[8:].decode().split(",") if n]  # ur_rtde ends the list with ","
                    types = [_variable_type(n, inputs=False) for n in names]
                    self.requested_outputs = names
                    outputs = _Recipe(1, names, types)
                    missing = [n for n, t in zip(names, types, strict=True) if t == "NOT_FOUND"]
                    if missing:
                        logger.warning("RTDE emulator: unknown output variables %s", missing)
                    self._send(conn, ptype, struct.pack(">B", 1) + ",".join(types).encode(), send_lock)
                elif ptype == RTDE_CONTROL_PACKAGE_SETUP_INPUTS:
                    names = [n for n in payload.decode().split(",") if n]
                    types = [_variable_type(n, inputs=True) for n in names]
                    recipe_id = len(inputs) + 2 if "NOT_FOUND" not in types else 0
                    if recipe_id:
                        inputs[recipe_id] = _Recipe(recipe_id, names, types)
                    self._send(conn, ptype, struct.pack(">B", recipe_id) + ",".join(types).encode(), send_lock)
                elif ptype == RTDE_CONTROL_PACKAGE_START:
                    ok = outputs is not None and "NOT_FOUND" not in outputs.types
                    self._send(conn, ptype, struct.pack(">B", int(ok)), send_lock)
                    if ok and not streaming.is_set():
                        streaming.set()
                        threading.Thread(
                            target=self._stream,
                            args=(conn, outputs, frequency, streaming, send_lock),
                            name="rtde-emulator-stream",
                            daemon=True,
                        ).start()
                elif ptype == RTDE_CONTROL_PACKAGE_PAUSE:
                    streaming.clear()
                    self._send(conn, ptype, struct.pack(">B", 1), send_lock)
                elif ptype == RTDE_DATA_PACKAGE:
                    recipe = inputs.get(payload[0])
                    if recipe is not None:
                        values = struct.unpack(recipe.fmt, payload[1:])
                        self._store_inputs(recipe, values)
                elif ptype == RTDE_TEXT_MESSAGE:
                    pass
                else:
                    logger.warning("RTDE emulator: ignoring package type %r", chr(ptype))
        except (ConnectionError, OSError, struct.error):
            pass
        finally:
            streaming.clear()
            with self._lock:
                if conn in self._clients:
                    self._clients.remove(conn)
            conn.close()

    def _store_inputs(self, recipe: _Recipe, values: tuple) -> None:
        it = iter(values)
        for name, rtype in zip(recipe.names, recipe.types, strict=True):
            n = {"VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}.get(rtype, 1)
            vals = [next(it) for _ in range(n)]
            self.inputs[name] = vals if n > 1 else vals[0]

    def _stream(self, conn, recipe: _Recipe, frequency: float, streaming: threading.Event, lock) -> None:
        period = 1.0 / max(float(frequency), 1.0)
        next_t = time.perf_counter()
        t0 = next_t
        try:
            while streaming.is_set() and self._running.is_set():
                values = self._snapshot(time.perf_counter() - t0)
                flat: list = []
                for name, rtype in zip(recipe.names, recipe.types, strict=True):
                    v = values.get(name)
                    n = {"VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}.get(rtype, 1)
                    if v is None:
                        v = [0] * n if n > 1 else (False if rtype == "BOOL" else 0)
                    flat.extend(list(v) if n > 1 else [v])
                self._send(conn, RTDE_DATA_PACKAGE, struct.pack(">B", recipe.id) + struct.pack(recipe.fmt, *flat), lock)
                self.packages_sent += 1
                next_t += period
                delay = next_t - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                else:
                    next_t = time.perf_counter()
        except (OSError, struct.error):
            streaming.clear()

    def _snapshot(self, t: float) -> dict[str, Any]:
        state = self.arm.read_state()
        qd = self.arm.joint_velocities()
        stopped = self._protective_stop.is_set()
        tcp = rotvec_pose_from_pose6(state.tcp_pose)
        return {
            "timestamp": float(t),
            "actual_q": [float(x) for x in state.q],
            "target_q": [float(x) for x in state.q],
            "actual_qd": [float(x) for x in qd],
            "actual_TCP_pose": [float(x) for x in tcp],
            "target_TCP_pose": [float(x) for x in tcp],
            "robot_mode": ROBOT_MODE_RUNNING,
            "joint_mode": [253] * 6,  # JOINT_RUNNING_MODE
            "safety_mode": SAFETY_MODE_PROTECTIVE_STOP if stopped else SAFETY_MODE_NORMAL,
            "safety_status": SAFETY_MODE_PROTECTIVE_STOP if stopped else SAFETY_MODE_NORMAL,
            "safety_status_bits": _STATUS_BIT_PROTECTIVE_STOPPED if stopped else _STATUS_BIT_NORMAL,
            "robot_status_bits": 0b11,  # power on, program running
            "runtime_state": _RUNTIME_PLAYING,
            "speed_scaling": 1.0,
            "target_speed_fraction": 1.0,
            "actual_main_voltage": 48.0,
            "actual_robot_voltage": 48.0,
            "joint_temperatures": [30.0] * 6,
        }


def _emulator_process_main(host: str, port: int, pipe) -> None:
    """Child process: the MuJoCo twin + the RTDE server, driven by commands from :class:`RtdeEmulatorProcess`."""
    from .config_ur10e import UR10eConfig
    from .sim_backend import SimBackend

    arm = SimBackend(UR10eConfig(backend="sim"))
    arm.connect()
    emu = RtdeEmulator(arm, host, port)
    try:
        emu.start()
        pipe.send(("ready", emu.port))
    except OSError as e:
        pipe.send(("error", f"cannot listen on {host}:{port}: {e}"))
        arm.disconnect()
        return
    try:
        while True:
            try:
                cmd, *args = pipe.recv()
            except EOFError:
                break
            if cmd == "close":
                break
            if cmd == "state":
                st = arm.read_state()
                pipe.send((st.q.tolist(), st.tcp_pose.tolist(), float(np.abs(arm.joint_velocities()).max())))
            elif cmd == "servo_tcp":
                arm.servo_tcp(np.asarray(args[0], dtype=np.float64))
                pipe.send(True)
            elif cmd == "stop":
                arm.stop()
                pipe.send(True)
            elif cmd == "protective_stop":
                emu.protective_stop()
                pipe.send(True)
            elif cmd == "clear_faults":
                emu._protective_stop.clear()
                pipe.send(True)
            elif cmd == "drop_connections":
                emu.drop_connections()
                pipe.send(True)
            elif cmd == "status":
                pipe.send({"clients": emu.client_count, "protective_stop": emu._protective_stop.is_set(),
                           "packages_sent": emu.packages_sent, "requested_outputs": emu.requested_outputs})
            else:
                pipe.send(ValueError(f"unknown command {cmd!r}"))
    finally:
        emu.stop()
        arm.disconnect()


class RtdeEmulatorProcess:
    """:class:`RtdeEmulator` + MuJoCo twin in a child process (see module doc for why), with fault hooks.

    ur_rtde's receive interface always connects to port 30004, so give each emulator its own loopback address
    (any 127.x.y.z works on Linux) when several may run at once.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 30004, start_timeout_s: float = 120.0):
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        self.host = host
        self._pipe, child = ctx.Pipe()
        self._lock = threading.Lock()
        self._proc = ctx.Process(target=_emulator_process_main, args=(host, port, child), daemon=True)
        self._proc.start()
        if not self._pipe.poll(start_timeout_s):
            self.close()
            raise TimeoutError(f"RTDE emulator did not start within {start_timeout_s} s")
        status, value = self._pipe.recv()
        if status != "ready":
            self.close()
            raise OSError(value)
        self.port = int(value)

    def _call(self, *msg):
        with self._lock:
            self._pipe.send(msg)
            reply = self._pipe.recv()
        if isinstance(reply, Exception):
            raise reply
        return reply

    def arm_state(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(joint positions, TCP pose6, max |joint velocity|) of the simulated arm behind the controller."""
        q, tcp, speed = self._call("state")
        return np.array(q), np.array(tcp), speed

    def servo_tcp(self, pose6) -> None:
        self._call("servo_tcp", [float(x) for x in pose6])

    def stop_arm(self) -> None:
        self._call("stop")

    def protective_stop(self) -> None:
        self._call("protective_stop")

    def drop_connections(self) -> None:
        self._call("drop_connections")

    def clear_faults(self) -> None:
        """Unlock a protective stop (what the operator does on the teach pendant)."""
        self._call("clear_faults")

    def status(self) -> dict:
        return self._call("status")

    def close(self) -> None:
        if self._proc.is_alive():
            try:
                with self._lock:
                    self._pipe.send(("close",))
            except (OSError, BrokenPipeError):
                pass
            self._proc.join(timeout=10)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=5)

    def __enter__(self) -> RtdeEmulatorProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class FakeRTDEControlInterface:
    """FAKE of ``rtde_control.RTDEControlInterface`` — the one boundary the emulator cannot serve (see module
    doc). It implements only the calls ``RtdeBackend`` makes and applies them to the emulator's simulated arm.
    It shares the controller's connection fate: once the emulator has no RTDE client any more (a dropped
    connection) it reports disconnected and ``servoL`` returns False, as ur_rtde does when its script is gone;
    during a protective stop ``servoL`` returns False too.
    """

    def __init__(self, emulator: RtdeEmulatorProcess, hostname: str = "127.0.0.1", frequency: float = 500.0):
        self.emulator = emulator
        self.hostname, self.frequency = hostname, frequency
        self.calls: list[str] = []
        self.tcp_offset: list[float] | None = None
        self._connected = True

    def _alive(self) -> bool:
        if self._connected and self.emulator.status()["clients"] == 0:
            self._connected = False
        return self._connected

    def isConnected(self) -> bool:  # noqa: N802 - ur_rtde's API
        return self._alive()

    def setTcp(self, pose: list[float]) -> bool:  # noqa: N802
        self.calls.append("setTcp")
        self.tcp_offset = list(pose)
        return True

    def servoL(self, pose, speed, acceleration, time_s, lookahead_time, gain) -> bool:  # noqa: N802
        self.calls.append("servoL")
        if not self._alive() or self.emulator.status()["protective_stop"]:
            return False
        self.emulator.servo_tcp(pose6_from_rotvec_pose(pose))
        return True

    def servoStop(self, a: float = 10.0) -> bool:  # noqa: N802
        self.calls.append("servoStop")
        self.emulator.stop_arm()
        return True

    def speedStop(self, a: float = 10.0) -> bool:  # noqa: N802
        self.calls.append("speedStop")
        self.emulator.stop_arm()
        return True

    def stopScript(self) -> None:  # noqa: N802
        self.calls.append("stopScript")

    def disconnect(self) -> None:
        self.calls.append("disconnect")
        self._connected = False


def _main() -> None:  # pragma: no cover - manual tool
    import argparse

    from .config_ur10e import UR10eConfig
    from .sim_backend import SimBackend

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=30004)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    arm = SimBackend(UR10eConfig(backend="sim"))
    arm.connect()
    with RtdeEmulator(arm, args.host, args.port) as emu:
        logger.info("RTDE emulator on %s:%d (Ctrl-C to stop)", args.host, emu.port)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
    arm.disconnect()


if __name__ == "__main__":  # pragma: no cover
    _main()


__all__ = ["FakeRTDEControlInterface", "RtdeEmulator"]
