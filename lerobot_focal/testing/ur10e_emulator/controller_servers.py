"""The three TCP servers of an emulated UR controller: RTDE (30004), dashboard (29999), script port (30003).

Each is socket I/O around an :class:`.emulated_controller.EmulatedController`, which decides every answer.
ur_rtde dials these ports on whatever address it is given, so several emulators run side by side on different
loopback addresses (any 127.x.y.z on Linux).
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from typing import Any

from . import rtde_protocol as rp
from .emulated_controller import EmulatedController

logger = logging.getLogger(__name__)

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003
CB3_MAX_FREQUENCY = 125.0
MAX_FREQUENCY = 500.0


class _TcpServer:
    """Accept loop on (host, port) that hands each connection to :meth:`serve` on its own thread."""

    name = "server"

    def __init__(self, controller: EmulatedController, host: str, port: int):
        self.controller, self.host, self._port = controller, host, port
        self._sock: socket.socket | None = None
        self._running = threading.Event()
        self._conns: set[socket.socket] = set()
        self._lock = threading.Lock()
        self.connections_total = 0

    @property
    def port(self) -> int:
        assert self._sock is not None, "not started"
        return self._sock.getsockname()[1]

    def start(self) -> _TcpServer:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((self.host, self._port))
        sock.listen(8)
        sock.settimeout(0.2)
        self._sock = sock
        self._running.set()
        threading.Thread(target=self._accept_loop, name=f"ur-{self.name}", daemon=True).start()
        return self

    def stop(self) -> None:
        self._running.clear()
        self.drop_connections()
        if self._sock is not None:
            self._sock.close()

    def drop_connections(self) -> None:
        with self._lock:
            conns, self._conns = self._conns, set()
        for c in conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()

    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._conns)

    def _accept_loop(self) -> None:
        while self._running.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            conn.settimeout(None)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._conns.add(conn)
                self.connections_total += 1
            threading.Thread(
                target=self._serve_and_close, args=(conn,), name=f"ur-{self.name}-conn", daemon=True
            ).start()

    def _serve_and_close(self, conn: socket.socket) -> None:
        try:
            self.serve(conn)
        except (ConnectionError, OSError, struct.error, UnicodeDecodeError):
            pass
        except Exception:  # noqa: BLE001 - one bad client must not take the server down
            logger.exception("%s: client handler failed", self.name)
        finally:
            self.on_close(conn)
            with self._lock:
                self._conns.discard(conn)
            conn.close()

    def serve(self, conn: socket.socket) -> None:
        raise NotImplementedError

    def on_close(self, conn: socket.socket) -> None:
        pass


class DashboardServer(_TcpServer):
    """Line protocol: a greeting on connect, then one reply line per request line."""

    name = "dashboard"

    def serve(self, conn: socket.socket) -> None:
        conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
        buf = b""
        while self._running.is_set():
            chunk = conn.recv(4096)
            if not chunk:
                return
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                reply = self.controller.dashboard(line.decode(errors="replace"))
                conn.sendall(reply.encode() + b"\n")
                if reply == "Disconnected":
                    return


class ScriptServer(_TcpServer):
    """Primary/secondary script port: a complete ``def name(): ... end`` program starts running."""

    name = "script"

    def serve(self, conn: socket.socket) -> None:
        buf = ""
        while self._running.is_set():
            chunk = conn.recv(65536)
            if not chunk:
                return
            buf += chunk.decode(errors="replace")
            stripped = buf.strip()
            if stripped.startswith(("def ", "sec ")) and stripped.endswith("end"):
                self.controller.upload_script(stripped)
                buf = ""


class RtdeServer(_TcpServer):
    """RTDE protocol v2 (see :mod:`.rtde_protocol`); the client owning ``input_int_register_0`` drives the script.

    Input variables belong to the connection that set them up first: a second client asking for them gets
    ``IN_USE`` (what a controller answers to a second ``RTDEControlInterface``) until the first disconnects.
    """

    name = "rtde"

    def __init__(self, controller: EmulatedController, host: str, port: int):
        super().__init__(controller, host, port)
        self._claims: dict[str, int] = {}  # input variable -> id of the connection that owns it
        self.requested_outputs: list[list[str]] = []  # every output recipe asked for (diagnostics, tests)
        self.output_frequencies: list[float] = []
        self.in_use_refusals = 0
        self._cache: tuple[float, dict[str, Any]] | None = None
        self._cache_lock = threading.Lock()

    def _outputs(self) -> dict[str, Any]:
        """Output values, computed at most once per millisecond for all connections."""
        now = time.monotonic()
        with self._cache_lock:
            if self._cache is None or now - self._cache[0] > 0.001:
                self._cache = (now, self.controller.outputs())
            return self._cache[1]

    def on_close(self, conn: socket.socket) -> None:
        with self._lock:
            for name in [n for n, owner in self._claims.items() if owner == id(conn)]:
                del self._claims[name]

    def _wait_out_stall(self) -> None:
        while self.controller.stalled() and self._running.is_set():
            time.sleep(0.002)

    def serve(self, conn: socket.socket) -> None:
        send_lock = threading.Lock()
        outputs: rp.Recipe | None = None
        inputs: dict[int, rp.Recipe] = {}
        frequency = MAX_FREQUENCY
        streaming = threading.Event()
        major = self.controller.version[0]
        try:
            while self._running.is_set():
                ptype, payload = rp.read_package(conn)
                self._wait_out_stall()
                if ptype == rp.REQUEST_PROTOCOL_VERSION:
                    (version,) = struct.unpack(">H", payload)
                    rp.send_package(conn, ptype, struct.pack(">B", int(version in (1, 2))), send_lock)
                elif ptype == rp.GET_URCONTROL_VERSION:
                    rp.send_package(conn, ptype, struct.pack(">IIII", *self.controller.version), send_lock)
                elif ptype == rp.SETUP_OUTPUTS:
                    (frequency,) = struct.unpack(">d", payload[:8])
                    names = [n for n in payload[8:].decode().split(",") if n]
                    types = [rp.variable_type(n, inputs=False) for n in names]
                    limit = CB3_MAX_FREQUENCY if major <= 3 else MAX_FREQUENCY
                    ok = all(t != rp.NOT_FOUND for t in types) and 0 < frequency <= limit
                    self.requested_outputs.append(names)
                    self.output_frequencies.append(frequency)
                    if not ok:
                        logger.warning("RTDE: refused output setup at %.0f Hz: %s", frequency,
                                       [n for n, t in zip(names, types, strict=True) if t == rp.NOT_FOUND])
                    outputs = rp.Recipe(1, names, types) if ok else None
                    rp.send_package(conn, ptype, struct.pack(">B", int(ok)) + ",".join(types).encode(), send_lock)
                elif ptype == rp.SETUP_INPUTS:
                    names = [n for n in payload.decode().split(",") if n]
                    types = self._claim_inputs(conn, names)
                    ok = all(t in rp.TYPE_FORMATS for t in types)
                    recipe_id = len(inputs) + 1 if ok else 0
                    if ok:
                        inputs[recipe_id] = rp.Recipe(recipe_id, names, types)
                    rp.send_package(conn, ptype, struct.pack(">B", recipe_id) + ",".join(types).encode(), send_lock)
                elif ptype == rp.START:
                    ok = outputs is not None
                    rp.send_package(conn, ptype, struct.pack(">B", int(ok)), send_lock)
                    if ok and not streaming.is_set():
                        streaming.set()
                        threading.Thread(
                            target=self._stream, args=(conn, outputs, frequency, streaming, send_lock),
                            name="ur-rtde-stream", daemon=True,
                        ).start()  # fmt: skip
                elif ptype == rp.PAUSE:
                    streaming.clear()
                    rp.send_package(conn, ptype, struct.pack(">B", 1), send_lock)
                elif ptype == rp.DATA_PACKAGE:
                    recipe = inputs.get(payload[0])
                    if recipe is not None:
                        values = recipe.unpack(payload[1:])
                        if self._owns(conn, "input_int_register_0") and "input_int_register_0" in values:
                            self.controller.on_registers(recipe.recipe_id, values)
                elif ptype != rp.TEXT_MESSAGE:
                    logger.warning("RTDE: ignoring package type %r", chr(ptype))
        finally:
            streaming.clear()

    def _claim_inputs(self, conn: socket.socket, names: list[str]) -> list[str]:
        types = [rp.variable_type(n, inputs=True) for n in names]
        with self._lock:
            taken = [n for n in names if self._claims.get(n, id(conn)) != id(conn)]
            if taken:
                self.in_use_refusals += 1
                return [rp.IN_USE if n in taken else t for n, t in zip(names, types, strict=True)]
            for n, t in zip(names, types, strict=True):
                if t in rp.TYPE_FORMATS:
                    self._claims[n] = id(conn)
        return types

    def _owns(self, conn: socket.socket, name: str) -> bool:
        with self._lock:
            return self._claims.get(name) == id(conn)

    def _stream(self, conn, recipe: rp.Recipe, frequency: float, streaming: threading.Event, lock) -> None:
        period = 1.0 / max(float(frequency), 1.0)
        next_t = time.perf_counter()
        try:
            while streaming.is_set() and self._running.is_set():
                if not self.controller.stalled():
                    rp.send_package(conn, rp.DATA_PACKAGE, recipe.pack(self._outputs()), lock)
                next_t += period
                delay = next_t - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                else:
                    next_t = time.perf_counter()
        except (OSError, struct.error):
            streaming.clear()
