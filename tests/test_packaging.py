"""The installed package, not the source checkout: a wheel built from this tree, installed into a fresh venv,
ships the training presets and `lerobot-focal-config` finds them (users who `pip install` get no configs/)."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.subprocess  # pip builds a wheel into a fresh venv

REPO = Path(__file__).resolve().parents[1]


def test_wheel_ships_the_presets_and_the_config_command(tmp_path):
    dist = tmp_path / "dist"
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(dist), str(REPO)],
        capture_output=True, text=True, timeout=600,
    )
    assert build.returncode == 0, build.stdout[-2000:] + build.stderr[-2000:]
    (wheel,) = dist.glob("lerobot_policy_focal-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for preset in ("focal_paper.json", "focal_cpu.json", "focal_cpu_state.json"):
        assert f"lerobot_focal/presets/{preset}" in names

    venv = tmp_path / "fresh"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    # The fresh venv sees this environment's dependencies (LeRobot, torch) through a path entry, but not its
    # editable install of this project (path entries' own .pth files are not processed): the project comes
    # from the wheel alone.
    site = Path(sysconfig.get_paths()["purelib"])
    fresh_site = next((venv / "lib").glob("python3*/site-packages"))
    (fresh_site / "deps.pth").write_text(str(site) + "\n")
    install = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "--no-deps", "-q",
         str(wheel)], capture_output=True, text=True, timeout=600,
    )
    assert install.returncode == 0, install.stdout[-2000:] + install.stderr[-2000:]
    where = subprocess.run([str(venv / "bin" / "python"), "-c", "import lerobot_focal; print(lerobot_focal.__file__)"],
                           capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert where.returncode == 0 and where.stdout.strip().startswith(str(fresh_site)), where.stdout + where.stderr
    out = subprocess.run([str(venv / "bin" / "lerobot-focal-config"), "cpu"], capture_output=True, text=True,
                         timeout=300, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    path = Path(out.stdout.strip())
    assert path.is_file() and str(path).startswith(str(venv)) and REPO not in path.parents
    preset = json.loads(path.read_text())
    assert preset["policy"]["type"] == "focal" and preset["policy"]["use_images"] is False
    bad = subprocess.run([str(venv / "bin" / "lerobot-focal-config"), "gpu"], capture_output=True, text=True,
                         timeout=300)
    assert bad.returncode == 2 and "choose one of paper, cpu, cpu_state" in bad.stderr
