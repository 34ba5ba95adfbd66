"""Finding LeRobot's console scripts (`lerobot-train`, `lerobot-eval`, ...) for the subprocesses we start."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path


def console_script(name: str) -> str:
    """The script next to this interpreter (its venv), else whatever is on PATH: a venv used without activation
    must still run its own LeRobot, not another one."""
    local = Path(sys.executable).with_name(name)
    return str(local) if local.exists() else (shutil.which(name) or name)
