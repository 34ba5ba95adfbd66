"""Test support for the emulated UR controller: free loopback addresses and robot configs pointed at them.

ur_rtde dials fixed ports (30004 RTDE, 29999 dashboard, 30003 script), so parallel emulators — other test
sessions on the same machine included — need different loopback addresses. Linux routes all of 127/8 to lo.
"""

from __future__ import annotations

import contextlib
import faulthandler
import random
import socket
import time
from collections.abc import Iterator
from pathlib import Path

from lerobot_focal.robots.ur10e import UR10eConfig
from lerobot_focal.robots.ur10e.safety import SafetyConfig

PORTS = (30004, 29999, 30003)


def free_loopback_host(attempts: int = 50) -> str:
    """A 127.x.y.z address on which all three controller ports can be bound right now."""
    rng = random.SystemRandom()
    for _ in range(attempts):
        host = f"127.{rng.randint(1, 254)}.{rng.randint(0, 254)}.{rng.randint(2, 254)}"
        socks = []
        try:
            for port in PORTS:
                s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                socks.append(s)
                s.bind((host, port))
            return host
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise RuntimeError("no free loopback address for an emulated UR controller")


def rtde_config(host: str, calibration_dir: Path, watchdog_s: float = 1.0, **overrides) -> UR10eConfig:
    """The rtde backend pointed at an emulator; RTDE at 125 Hz keeps the two-core test machine's load low."""
    kwargs = dict(
        backend="rtde",
        robot_ip=host,
        rtde_frequency=125.0,
        gripper="none",
        calibration_dir=calibration_dir,
        safety=SafetyConfig(watchdog_timeout_s=watchdog_s),
    )
    kwargs.update(overrides)
    return UR10eConfig(**kwargs)


@contextlib.contextmanager
def hard_deadline(seconds: float) -> Iterator[None]:
    """End the test process (with every thread's traceback) if the block runs past `seconds`.

    ur_rtde's constructors hold the GIL while they wait on the socket, and its RTDE setup has no client-side
    timeout, so a Python-level timeout (pytest-timeout, signal handlers) cannot fire while they hang.
    faulthandler's watchdog is a C thread that needs no GIL.
    """
    faulthandler.dump_traceback_later(seconds, exit=True)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def wait_still(emulator, timeout_s: float = 5.0) -> float:
    """Wait (bounded) until the emulated arm stops; returns its last TCP speed (m/s)."""
    deadline = time.monotonic() + timeout_s
    speed = emulator.arm_state()[2]
    while speed > 1e-3 and time.monotonic() < deadline:
        time.sleep(0.05)
        speed = emulator.arm_state()[2]
    return speed
