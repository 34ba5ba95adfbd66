"""Finding LeRobot's console scripts (`lerobot-train`, `lerobot-eval`, ...) for the subprocesses we start, and
the parsers of our own commands."""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path


def console_script(name: str) -> str:
    """The script next to this interpreter (its venv), else whatever is on PATH: a venv used without activation
    must still run its own LeRobot, not another one."""
    local = Path(sys.executable).with_name(name)
    return str(local) if local.exists() else (shutil.which(name) or name)


def doc_parser(doc: str | None, prog: str | None = None) -> argparse.ArgumentParser:
    """A parser whose ``--help`` is the command's module docstring, line breaks kept: the docstrings hold the
    usage examples, and argparse's default formatter would run them together."""
    return argparse.ArgumentParser(prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
