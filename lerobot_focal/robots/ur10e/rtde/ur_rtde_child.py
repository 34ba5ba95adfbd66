"""Child process that owns ur_rtde's RTDEReceiveInterface and RTDEControlInterface (run by path, see below).

ur_rtde is treated as untrusted: its constructors hold the GIL while they connect, some calls block for
seconds (moveL up to 300 s, stopScript ~4 s) when the controller is gone, methods report failures only on
stderr, and on PolyScope X the process can segfault on reconnect. Inside this process it can do all of that
without stopping the robot process: :mod:`.rtde_session` talks to it over a socket pair, never waits on it in
the control loop, and notices when it dies.

Protocol (pickled tuples over ``multiprocessing.connection.Connection``):

* parent -> child: ``("call", req_id, method, args)`` (``req_id`` None: no reply wanted, failures reported as
  ``("failed", method, result)``), ``("close",)``.
* child -> parent: ``("ready", info)`` or ``("error", message)`` once; then ``("state", snapshot)`` every
  ``--period`` seconds and ``("reply", req_id, ok, value)`` per call with an id.

It imports nothing from the project (only the standard library and ur_rtde), so it starts in ~0.1 s; it is run
as ``python ur_rtde_child.py --fd N --host ... --frequency ...``.
"""

from __future__ import annotations

import argparse
import time
from multiprocessing.connection import Connection


def _snapshot(recv, ctrl) -> dict:
    return {
        "timestamp": recv.getTimestamp(),
        "q": list(recv.getActualQ()),
        "tcp": list(recv.getActualTCPPose()),
        "safety_mode": int(recv.getSafetyMode()),
        "safety_status_bits": int(recv.getSafetyStatusBits()),
        "robot_status_bits": int(recv.getRobotStatus()),
        "runtime_state": int(recv.getRuntimeState()),
        "protective_stopped": bool(recv.isProtectiveStopped()),
        "emergency_stopped": bool(recv.isEmergencyStopped()),
        "recv_connected": bool(recv.isConnected()),
        "ctrl_connected": bool(ctrl.isConnected()),
        "program_running": bool(ctrl.isProgramRunning()),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--fd", type=int, required=True)
    parser.add_argument("--host", required=True)
    parser.add_argument("--frequency", type=float, default=-1.0)
    parser.add_argument("--period", type=float, default=0.01)
    args = parser.parse_args()
    conn = Connection(args.fd)
    try:
        import rtde_control
        import rtde_receive

        recv = rtde_receive.RTDEReceiveInterface(args.host, args.frequency)
        ctrl = rtde_control.RTDEControlInterface(args.host, args.frequency)
    except Exception as e:  # noqa: BLE001 - whatever ur_rtde raises goes to the parent as text
        conn.send(("error", f"{type(e).__name__}: {e}"))
        return
    conn.send(("ready", {"frequency": args.frequency}))
    next_snapshot = 0.0
    try:
        while True:
            now = time.monotonic()
            if now >= next_snapshot:
                try:
                    conn.send(("state", _snapshot(recv, ctrl)))
                except (OSError, EOFError):
                    return
                except Exception as e:  # noqa: BLE001
                    conn.send(("state", {"error": f"{type(e).__name__}: {e}"}))
                next_snapshot = now + args.period
            if not conn.poll(max(0.0, next_snapshot - time.monotonic())):
                continue
            msg = conn.recv()
            if msg[0] == "close":
                break
            _, req_id, method, call_args = msg
            target = recv if method.startswith(("get", "is")) and hasattr(recv, method) else ctrl
            try:
                value, ok = getattr(target, method)(*call_args), True
            except Exception as e:  # noqa: BLE001
                value, ok = f"{type(e).__name__}: {e}", False
            if req_id is not None:
                conn.send(("reply", req_id, ok, value))
            elif not ok or value is False:
                conn.send(("failed", method, value))
    except (EOFError, OSError):
        pass  # the parent went away
    finally:
        for iface in (ctrl, recv):
            try:
                iface.disconnect()
            except Exception:  # noqa: BLE001
                pass


if __name__ == "__main__":
    main()
