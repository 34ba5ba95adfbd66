"""The grid's child processes (demo collection, `lerobot-train`, `lerobot-eval`, analysis), stoppable as one.

Every child runs in its own session, so a terminal's Ctrl-C reaches only the driver, which then stops them in
order with :func:`stop_all`; once it has, no new child starts and every caller gets :class:`GridStopped`.
"""

from __future__ import annotations

import logging
import subprocess
import threading
from collections.abc import Callable
from pathlib import Path


class RunFailed(RuntimeError):
    """A run that did not produce results; the message says which step and where its log is."""


class GridStopped(RuntimeError):
    """The grid is being interrupted: do not start (or retry) anything."""


_RUNNING: set[subprocess.Popen] = set()  # children in flight in this process
_STOPPING = threading.Event()


def refuse_if_stopping() -> None:
    if _STOPPING.is_set():
        raise GridStopped("the grid is stopping")


def stop_all() -> None:
    """Stop every child in flight in this process and refuse new ones (the driver's Ctrl-C path)."""
    _STOPPING.set()
    for proc in list(_RUNNING):
        proc.terminate()
    for proc in list(_RUNNING):
        _reap(proc)


def _reap(proc: subprocess.Popen) -> None:
    """Wait for a terminated child; kill it if it has not ended within 20 s."""
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()


def _wait(proc: subprocess.Popen, poll: Callable[[], None] | None, every_s: float) -> int:
    while True:
        try:
            return proc.wait(timeout=every_s if poll else None)
        except subprocess.TimeoutExpired:
            try:
                poll()
            except Exception as err:  # noqa: BLE001 - housekeeping must never stop the run it looks after
                logging.warning("housekeeping beside pid %d failed (the run goes on): %s", proc.pid, err)


def run_logged(cmd: list[str], log: Path, env: dict[str, str], what: str,
               poll: Callable[[], None] | None = None, poll_every_s: float = 20.0) -> None:
    """Run `cmd` with its output appended to `log`; RunFailed (with the log's tail) if it exits non-zero.

    ``poll`` is called every ``poll_every_s`` seconds while the child runs (housekeeping such as pruning old
    checkpoints, logging progress); an error it raises is logged, never fatal to the run."""
    refuse_if_stopping()
    with open(log, "ab") as f:
        f.write(f"\n$ {' '.join(cmd)}\n".encode())
        f.flush()
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        _RUNNING.add(proc)
        try:
            rc = _wait(proc, poll, poll_every_s)
        except BaseException:  # Ctrl-C in a single-job driver lands here: the child is in its own session
            proc.terminate()
            _reap(proc)
            raise
        finally:
            _RUNNING.discard(proc)
    refuse_if_stopping()
    if rc != 0:
        tail = log.read_text(errors="replace").splitlines()[-15:]
        raise RunFailed(f"{what} exited with {rc}; log: {log}\n" + "\n".join(tail))
