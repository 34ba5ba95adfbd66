"""The system libraries the README's set-up installs (scripts/system_libs.sh) are there and used: a LeRobot
command runs without torchcodec's FFmpeg loading traceback, and OSMesa is found (the OpenGL comparison in
tests/envs/test_pointcloud.py needs it and fails without it)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.subprocess  # scripts/system_libs.sh and lerobot-info

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def test_system_libs_check_passes():
    proc = subprocess.run([str(REPO / "scripts" / "system_libs.sh"), "--check"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "FFmpeg (torchcodec), OSMesa" in proc.stdout


def test_lerobot_command_loads_torchcodec_quietly():
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    proc = subprocess.run([str(BIN / "lerobot-info")], capture_output=True, text=True, timeout=300, env=env)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert "libtorchcodec" not in out and "Falling back to 'pyav'" not in out, (
        "torchcodec cannot load FFmpeg: run ./scripts/setup.sh (installs ffmpeg) or apt-get install ffmpeg\n"
        + out[-3000:]
    )


def test_check_finds_ldconfig_outside_a_users_path():
    """A Debian user's PATH has no /sbin, where ldconfig lives: the check must still see the installed libraries."""
    env = {**os.environ, "PATH": "/usr/local/bin:/usr/bin:/bin"}
    proc = subprocess.run(
        ["bash", str(REPO / "scripts" / "system_libs.sh"), "--check"], capture_output=True, text=True, timeout=60,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr


def test_fresh_machine_check_stops_before_building_without_a_python_312(tmp_path):
    """scripts/fresh_machine_check.sh needs a Python 3.12 to carry into the bare root: without one it says how to
    get one and creates nothing (no root directory, no debootstrap)."""
    root = tmp_path / "root"
    env = {**os.environ, "PYTHON312_ROOT": str(tmp_path / "no_pyenv"), "ROOT": str(root)}
    proc = subprocess.run(["bash", str(REPO / "scripts" / "fresh_machine_check.sh")], capture_output=True,
                          text=True, timeout=60, env=env)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert f"no Python 3.12 under {tmp_path / 'no_pyenv'}/versions" in proc.stderr
    assert "pyenv install 3.12" in proc.stderr
    assert not root.exists()
