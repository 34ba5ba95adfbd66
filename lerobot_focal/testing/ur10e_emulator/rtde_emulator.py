"""An emulated UR controller on loopback: RTDE (30004), dashboard (29999), script port (30003), MuJoCo twin.

A test harness (the rtde backend's tests run against it) that also runs from the CLI (below).

ur_rtde 1.6.5's *real* ``RTDEReceiveInterface`` and ``RTDEControlInterface`` run against it: the control
interface negotiates RTDE, talks to the dashboard, uploads its control script on the script port and then
commands the arm through RTDE registers, which :mod:`.control_script` plays (an emulator never runs URScript).
Commanded motion moves the MuJoCo twin, whose state streams back as RTDE outputs.

Pieces: :mod:`.rtde_protocol` (wire format), :mod:`.control_script` (the script's register state machine),
:mod:`.emulated_controller` (robot / safety / runtime state and the dashboard's answers),
:mod:`.controller_servers` (the three TCP servers), and this module (the whole controller, in a child process,
with fault hooks for tests, and a CLI).

ur_rtde's Python bindings hold the GIL while their constructors block on a socket, so a client in the same
process as the server would deadlock: :class:`RtdeEmulatorProcess` runs the controller in a child process. The
ports are fixed in ur_rtde; run several emulators on different loopback addresses (127.x.y.z).

Run it standalone, then point the robot at it with ``--robot.backend=rtde --robot.robot_ip=127.0.0.1``::

    python -m lerobot_focal.testing.ur10e_emulator.rtde_emulator --host 127.0.0.1 --version 5.15.0.0
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from .controller_servers import DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT, DashboardServer, RtdeServer, ScriptServer
from .emulated_controller import ControllerOptions, EmulatedController

logger = logging.getLogger(__name__)


class ControllerEmulator:
    """The controller (state + servers) around a connected twin ``arm``. PolyScope X (major >= 10) has no
    dashboard server, so none is started for it."""

    def __init__(self, arm: Any, host: str = "127.0.0.1", options: ControllerOptions | None = None,
                 ports: tuple[int, int, int] = (RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT)):  # fmt: skip
        self.controller = EmulatedController(arm, options)
        self.host = host
        self.rtde = RtdeServer(self.controller, host, ports[0])
        self.dashboard = DashboardServer(self.controller, host, ports[1]) if self.controller.version[0] < 10 else None
        self.script = ScriptServer(self.controller, host, ports[2])

    def _servers(self) -> list:
        return [s for s in (self.rtde, self.dashboard, self.script) if s is not None]

    def start(self) -> ControllerEmulator:
        started = []
        try:
            for s in self._servers():
                s.start()
                started.append(s)
        except OSError:
            for s in started:
                s.stop()
            raise
        self.controller.start()
        return self

    def stop(self) -> None:
        self.controller.stop()
        for s in self._servers():
            s.stop()

    def drop_connections(self) -> None:
        for s in self._servers():
            s.drop_connections()

    def status(self) -> dict[str, Any]:
        c = self.controller
        return {
            "version": list(c.version),
            "runtime_state": c.runtime_state,
            "program_running": c.program_running,
            "protective_stop": c.protective_stopped,
            "protective_stop_cause": c.protective_stop_cause,
            "script_uploads": list(c.script_uploads),
            "dashboard_log": list(c.dashboard_log),
            "requested_outputs": [list(r) for r in self.rtde.requested_outputs],
            "output_frequencies": list(self.rtde.output_frequencies),
            "in_use_refusals": self.rtde.in_use_refusals,
            "rtde_clients": self.rtde.client_count,
            "rtde_connections_total": self.rtde.connections_total,
            "commands_total": c.script.commands_total,
            "script_registers": {"out_int": c.script.out_int[:3]},
        }


def _emulator_process_main(host: str, options: dict, pipe) -> None:
    """Child process: the MuJoCo twin + the controller, driven by requests from :class:`RtdeEmulatorProcess`."""
    from lerobot_focal.robots.ur10e.config_ur10e import UR10eConfig
    from lerobot_focal.robots.ur10e.twin.sim_backend import SimBackend

    arm = SimBackend(UR10eConfig(backend="sim"))
    arm.connect()
    emu = ControllerEmulator(arm, host, ControllerOptions(**options))
    try:
        emu.start()
    except OSError as e:
        pipe.send(("error", f"cannot listen on {host} (ports 30004/29999/30003): {e}"))
        arm.disconnect()
        return
    pipe.send(("ready", None))
    c = emu.controller
    handlers = {
        "state": lambda: (arm.read_state().q.tolist(), arm.read_state().tcp_pose.tolist(),
                          float(np.abs(arm.joint_velocities()).max())),  # fmt: skip
        "protective_stop": lambda cause="protective stop": c.protective_stop(cause),
        "stall": lambda seconds: c.stall(seconds),
        "drop_connections": emu.drop_connections,
        "status": emu.status,
        "commands": lambda since=0: c.script.recent_commands(since),
        "set_protective_stop_policy": lambda policy: setattr(c.options, "on_protective_stop", policy),
    }
    try:
        while True:
            try:
                cmd, args = pipe.recv()
            except EOFError:
                break
            if cmd == "close":
                break
            try:
                pipe.send(("ok", handlers[cmd](*args)))
            except Exception as e:  # noqa: BLE001 - reported to the parent
                pipe.send(("error", f"{cmd}: {e!r}"))
    finally:
        emu.stop()
        arm.disconnect()


class RtdeEmulatorProcess:
    """:class:`ControllerEmulator` + MuJoCo twin in a child process, with fault hooks for tests.

    ``version`` is the controller version it reports (e.g. ``(3, 15, 0, 0)`` for a CB3 at 125 Hz,
    ``(5, 23, 0, 0)``, ``(10, 7, 0, 0)`` for PolyScope X). :meth:`kill` ends it like a controller that dies.
    The child is a fresh interpreter (``python -m`` this module) talking over a socket pair, so it works from
    any parent, including console scripts whose main module cannot be re-imported.
    """

    def __init__(self, host: str = "127.0.0.1", version=(5, 15, 0, 0), on_protective_stop: str = "pause",
                 start_timeout_s: float = 120.0):  # fmt: skip
        import socket
        import subprocess
        from multiprocessing.connection import Connection

        self.host = host
        self._lock = threading.Lock()
        parent, child = socket.socketpair()
        args = [sys.executable, "-m", __name__, "--host", host, "--version", ".".join(str(v) for v in version),
                "--on-protective-stop", on_protective_stop, "--control-fd", str(child.fileno())]  # fmt: skip
        # The child must import this very package (not another installed copy).
        package_root = str(Path(__file__).resolve().parents[3])
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [package_root, os.environ.get("PYTHONPATH")])))
        self._proc = subprocess.Popen(args, pass_fds=[child.fileno()], env=env)
        child.close()
        self._pipe = Connection(parent.detach())
        if not self._pipe.poll(start_timeout_s):
            self.close()
            raise TimeoutError(f"the UR controller emulator did not start within {start_timeout_s} s")
        try:
            status, value = self._pipe.recv()
        except EOFError:
            status, value = "error", f"the emulator process exited with code {self._proc.wait(10)} while starting"
        if status != "ready":
            self.close()
            raise OSError(value)

    @property
    def pid(self) -> int | None:
        return self._proc.pid

    def _call(self, cmd: str, *args, timeout_s: float = 30.0):
        with self._lock:
            self._pipe.send((cmd, args))
            if not self._pipe.poll(timeout_s):
                raise TimeoutError(f"emulator did not answer {cmd!r} within {timeout_s} s")
            try:
                status, value = self._pipe.recv()
            except EOFError:
                raise RuntimeError(f"the emulator process has exited (code {self._proc.poll()})") from None
        if status != "ok":
            raise RuntimeError(value)
        return value

    def arm_state(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(joint positions, TCP pose6, max |joint velocity|) of the simulated arm behind the controller."""
        q, tcp, speed = self._call("state")
        return np.array(q), np.array(tcp), speed

    def protective_stop(self, cause: str = "protective stop") -> None:
        self._call("protective_stop", cause)

    def stall(self, seconds: float) -> None:
        """A network blip: no RTDE traffic either way for `seconds`; connections stay open."""
        self._call("stall", float(seconds))

    def drop_connections(self) -> None:
        self._call("drop_connections")

    def set_protective_stop_policy(self, policy: str) -> None:
        self._call("set_protective_stop_policy", policy)

    def status(self) -> dict:
        return self._call("status")

    def commands(self, since: int = 0) -> list[dict]:
        """Commands that reached the control script, with their raw registers (see control_script)."""
        return self._call("commands", since)

    def kill(self) -> None:
        """SIGKILL the controller: every socket closes at once, nothing is said on the wire."""
        if self._proc.poll() is None:
            os.kill(self._proc.pid, signal.SIGKILL)
            self._proc.wait(timeout=10)

    def close(self) -> None:
        if self._proc.poll() is None:
            try:
                with self._lock:
                    self._pipe.send(("close", ()))
            except (OSError, BrokenPipeError):
                pass
            try:
                self._proc.wait(timeout=10)
            except Exception:  # noqa: BLE001 - escalate below
                pass
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait(timeout=5)
        self._pipe.close()

    def __enter__(self) -> RtdeEmulatorProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def main(argv: list[str] | None = None) -> None:  # pragma: no cover - CLI
    import argparse

    from lerobot_focal.robots.ur10e.config_ur10e import UR10eConfig
    from lerobot_focal.robots.ur10e.twin.sim_backend import SimBackend

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--host", default="127.0.0.1", help="loopback address to serve on (127.x.y.z)")
    parser.add_argument("--version", default="5.15.0.0", help="controller version to report, e.g. 3.15.0.0")
    parser.add_argument("--on-protective-stop", choices=("pause", "stop"), default="pause")
    parser.add_argument("--control-fd", type=int, default=None, help=argparse.SUPPRESS)  # RtdeEmulatorProcess
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, force=True)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # stop cleanly (the finally below) on `kill`
    version = tuple(int(v) for v in args.version.split("."))
    if args.control_fd is not None:
        from multiprocessing.connection import Connection

        options = {"version": version, "on_protective_stop": args.on_protective_stop}
        _emulator_process_main(args.host, options, Connection(args.control_fd))
        return
    arm = SimBackend(UR10eConfig(backend="sim"))
    arm.connect()
    options = ControllerOptions(version, args.on_protective_stop)
    emu = ControllerEmulator(arm, args.host, options).start()
    logger.info("UR controller emulator %s on %s (RTDE 30004, dashboard 29999, script 30003); Ctrl-C stops it",
                args.version, args.host)
    try:
        while True:
            time.sleep(1.0)
    except (KeyboardInterrupt, SystemExit):
        pass
    finally:
        emu.stop()
        arm.disconnect()


if __name__ == "__main__":  # pragma: no cover
    main()


__all__ = ["ControllerEmulator", "RtdeEmulatorProcess"]
