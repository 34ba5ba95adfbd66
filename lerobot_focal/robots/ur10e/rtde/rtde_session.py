"""The robot process's side of ur_rtde: the client runs in a child process (:mod:`.ur_rtde_child`).

Why a child: ur_rtde's constructors hold the GIL while connecting, some of its calls block for seconds when
the controller is gone, failures only reach stderr, and on PolyScope X the client can segfault. So the robot
process never calls ur_rtde itself. It reads the newest state snapshot the child streams (a local read that
cannot block), sends commands without waiting for them (a refused command comes back as a failure event),
and learns that the child died from end-of-file on the socket pair. Calls that must be answered (connect,
re-upload the script, close) wait with a bound and report which bound was hit.

Also here: :func:`probe_controller_version` (RTDE's own version handshake, with socket timeouts) and
:class:`DashboardClient` (UR's line-based dashboard protocol on port 29999, with timeouts), both plain sockets
so they can never hang the robot process.
"""

from __future__ import annotations

import itertools
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

_CHILD = Path(__file__).with_name("ur_rtde_child.py")


class SessionError(ConnectionError):
    """The ur_rtde client process could not be started, did not answer in time, or has died."""


def probe_controller_version(host: str, timeout_s: float = 2.0, port: int = 30004) -> tuple[int, int, int, int]:
    """(major, minor, bugfix, build) from RTDE's handshake (protocol 2, then the controller version).

    Raises ConnectionError with the address when nothing answers within `timeout_s`.
    """
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as s:
            s.settimeout(timeout_s)
            s.sendall(struct.pack(">HBH", 5, ord("V"), 2))
            _read_package(s)
            s.sendall(struct.pack(">HB", 3, ord("v")))
            ptype, payload = _read_package(s)
            if ptype != ord("v") or len(payload) < 16:
                raise ConnectionError(f"unexpected RTDE reply type {ptype!r} from {host}:{port}")
            return tuple(int(x) for x in struct.unpack(">IIII", payload[:16]))  # type: ignore[return-value]
    except (OSError, struct.error) as e:
        raise ConnectionError(f"no UR controller answers RTDE at {host}:{port} ({e})") from e


def _read_package(s: socket.socket) -> tuple[int, bytes]:
    head = b""
    while len(head) < 3:
        chunk = s.recv(3 - len(head))
        if not chunk:
            raise ConnectionError("connection closed during the RTDE handshake")
        head += chunk
    size, ptype = struct.unpack(">HB", head)
    body = b""
    while len(body) < size - 3:
        chunk = s.recv(size - 3 - len(body))
        if not chunk:
            raise ConnectionError("connection closed during the RTDE handshake")
        body += chunk
    return ptype, body


PROTECTIVE_STOP_RELEASED = "Protective stop releasing"  # the dashboard's reply to an accepted unlock


class DashboardClient:
    """One request per call on UR's dashboard server (port 29999), every socket operation time-bounded."""

    def __init__(self, host: str, timeout_s: float = 2.5, port: int = 29999):
        self.host, self.port, self.timeout_s = host, port, timeout_s

    def request(self, line: str) -> str:
        try:
            with socket.create_connection((self.host, self.port), timeout=self.timeout_s) as s:
                s.settimeout(self.timeout_s)
                f = s.makefile("rb")
                f.readline()  # greeting
                s.sendall(line.encode() + b"\n")
                reply = f.readline().decode(errors="replace").strip()
                try:
                    s.sendall(b"quit\n")
                except OSError:
                    pass
                return reply
        except OSError as e:
            raise ConnectionError(f"dashboard server at {self.host}:{self.port} did not answer {line!r}: {e}") from e

    def unlock_protective_stop(self, timeout_s: float, retry_s: float = 0.5) -> str:
        """Ask until the stop is released or `timeout_s` passes (a controller refuses for 5 s after the stop
        occurred); returns the last reply, "Protective stop releasing" on success."""
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self.request("unlock protective stop")
            if reply.startswith(PROTECTIVE_STOP_RELEASED) or time.monotonic() + retry_s >= deadline:
                return reply
            time.sleep(retry_s)


@dataclass
class Snapshot:
    """The newest controller state the child read from RTDEReceiveInterface / RTDEControlInterface."""

    values: dict[str, Any] = field(default_factory=dict)
    received_at: float = 0.0  # monotonic time it arrived
    fresh_at: float = 0.0  # monotonic time the controller's timestamp last advanced


class RtdeSession:
    """ur_rtde's receive + control interfaces in a child process; see module docstring."""

    def __init__(self, host: str, frequency: float = -1.0, snapshot_period_s: float = 0.01):
        self.host, self.frequency, self.snapshot_period_s = host, frequency, snapshot_period_s
        self.snapshot = Snapshot()
        # Commands ur_rtde refused: (method, result, monotonic time the refusal arrived).
        self.failures: list[tuple[str, Any, float]] = []
        self._proc: subprocess.Popen | None = None
        self._conn: Connection | None = None
        self._send_lock = threading.Lock()
        self._replies: dict[int, tuple[threading.Event, list]] = {}
        self._ids = itertools.count(1)
        self._dead: str | None = None
        self._reader: threading.Thread | None = None

    # -- lifecycle --------------------------------------------------------------------------------------------
    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    def start(self, timeout_s: float = 30.0) -> RtdeSession:
        parent, child = socket.socketpair()
        args = [sys.executable, str(_CHILD), "--fd", str(child.fileno()), "--host", self.host,
                "--frequency", str(self.frequency), "--period", str(self.snapshot_period_s)]  # fmt: skip
        self._proc = subprocess.Popen(args, pass_fds=[child.fileno()], stdout=subprocess.DEVNULL)
        child.close()
        self._conn = Connection(parent.detach())
        if not self._conn.poll(timeout_s):
            self._kill()
            raise SessionError(f"ur_rtde did not connect to the UR controller at {self.host} within {timeout_s:.0f} s")
        try:
            msg = self._conn.recv()
        except (EOFError, OSError):
            code = self._exit_code()
            raise SessionError(f"the ur_rtde client process died while connecting ({code})") from None
        if msg[0] != "ready":
            self._kill()
            raise SessionError(f"ur_rtde could not connect to the UR controller at {self.host}: {msg[1]}")
        self._reader = threading.Thread(target=self._read_loop, name="ur-rtde-session", daemon=True)
        self._reader.start()
        return self

    def close(self, timeout_s: float = 3.0) -> None:
        """Ask the child to disconnect ur_rtde and exit; kill it when it does not within `timeout_s`."""
        if self._proc is None:
            return
        if self._dead is None and timeout_s > 0:
            try:
                with self._send_lock:
                    self._conn.send(("close",))
            except OSError:
                pass
        try:
            self._proc.wait(timeout_s) if timeout_s > 0 else self._kill()
        except subprocess.TimeoutExpired:
            self._kill()
        self._dead = self._dead or "closed"
        self._conn.close()

    def _kill(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait(5)

    def _exit_code(self, wait_s: float = 1.0) -> str:
        try:
            code = self._proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            return "still running"
        if code < 0:
            try:
                return f"killed by {signal.Signals(-code).name}"
            except ValueError:
                return f"killed by signal {-code}"
        return f"exit code {code}"

    # -- state ------------------------------------------------------------------------------------------------
    @property
    def dead(self) -> str | None:
        """None while the child runs; else why it stopped (e.g. "killed by SIGSEGV")."""
        return self._dead

    def _read_loop(self) -> None:
        last_ts = None
        while True:
            try:
                msg = self._conn.recv()
            except (EOFError, OSError):
                break
            kind = msg[0]
            if kind == "state":
                now = time.monotonic()
                values = msg[1]
                ts = values.get("timestamp")
                fresh = self.snapshot.fresh_at if ts == last_ts else now
                last_ts = ts
                self.snapshot = Snapshot(values, now, fresh)
            elif kind == "reply":
                _, req_id, ok, value = msg
                waiter = self._replies.pop(req_id, None)
                if waiter is not None:
                    waiter[1].extend([ok, value])
                    waiter[0].set()
            elif kind == "failed":
                self.failures.append((msg[1], msg[2], time.monotonic()))
        if self._dead is None:
            self._dead = self._exit_code()
        for event, _ in list(self._replies.values()):
            event.set()

    def _why_gone(self, err: OSError) -> str:
        """Why the pipe broke: the child's fate when it is already known (a broken pipe is usually noticed a
        moment before the reader thread reaps the child), else the pipe error. Waits at most 50 ms."""
        if self._dead is not None:
            return self._dead
        fate = self._exit_code(wait_s=0.05)
        return f"{fate}; {err}" if fate != "still running" else str(err)

    # -- calls ------------------------------------------------------------------------------------------------
    def send(self, method: str, *args: Any) -> None:
        """Fire and forget; a refusal shows up in :attr:`failures`. Never blocks on ur_rtde."""
        if self._dead is not None:
            raise SessionError(f"the ur_rtde client process is gone ({self._dead})")
        try:
            with self._send_lock:
                self._conn.send(("call", None, method, args))
        except OSError as e:
            raise SessionError(f"the ur_rtde client process is gone ({self._why_gone(e)})") from e

    def call(self, method: str, *args: Any, timeout_s: float) -> Any:
        """Call and wait for the answer at most `timeout_s`; raises SessionError on timeout or death."""
        if self._dead is not None:
            raise SessionError(f"the ur_rtde client process is gone ({self._dead})")
        req_id = next(self._ids)
        event: threading.Event = threading.Event()
        result: list = []
        self._replies[req_id] = (event, result)
        try:
            with self._send_lock:
                self._conn.send(("call", req_id, method, args))
        except OSError as e:
            raise SessionError(f"the ur_rtde client process is gone ({self._why_gone(e)})") from e
        if not event.wait(timeout_s):
            self._replies.pop(req_id, None)
            raise SessionError(f"ur_rtde's {method} did not return within {timeout_s:.1f} s")
        if not result:
            raise SessionError(f"the ur_rtde client process died during {method} ({self._dead})")
        ok, value = result
        if not ok:
            raise SessionError(f"ur_rtde's {method} raised {value}")
        return value

    def wait_for(self, predicate, timeout_s: float, poll_s: float = 0.01) -> bool:
        """Wait until predicate(snapshot values) is true (bounded); False on timeout or a dead child."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and self._dead is None:
            if self.snapshot.values and predicate(self.snapshot.values):
                return True
            time.sleep(poll_s)
        return False

    def signal_child(self, sig: int) -> None:
        """Test hook: deliver a signal to the ur_rtde process (e.g. SIGSEGV, as PolyScope X reconnects cause)."""
        if self._proc is not None and self._proc.poll() is None:
            os.kill(self._proc.pid, sig)
