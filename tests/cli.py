"""Running LeRobot's own command-line tools (installed in this venv) as a user would: a subprocess, offline."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

BIN = Path(sys.executable).parent


def run_lerobot(command: str, *args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    """`command` (e.g. "lerobot-train") with `args`, no hub, no wandb; stdout and stderr captured as text."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    return subprocess.run(
        [str(BIN / command), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )


def assert_config_error(proc: subprocess.CompletedProcess, message: str, config_class: str) -> None:
    """The command stopped at parse time with the config's own `message`, not draccus's, and no traceback."""
    assert proc.returncode != 0, f"the command accepted a bad value:\n{proc.stderr[-3000:]}"
    assert message in proc.stderr, proc.stderr[-3000:]
    assert f"Couldn't instantiate class {config_class}" not in proc.stderr, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
