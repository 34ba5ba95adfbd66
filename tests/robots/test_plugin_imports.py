"""Every lerobot-* CLI imports this plugin: registering the robot/teleop must not pull in the hardware stacks."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytestmark = pytest.mark.subprocess  # a fresh interpreter, to see what importing loads


def test_registration_imports_no_simulator_or_hardware_library():
    code = (
        "import sys, lerobot_focal.robots, lerobot_focal.teleoperators\n"
        "from lerobot.robots.config import RobotConfig\n"
        "from lerobot.teleoperators.config import TeleoperatorConfig\n"
        "assert RobotConfig.get_choice_class('ur10e').__name__ == 'UR10eConfig'\n"
        "assert TeleoperatorConfig.get_choice_class('focal_gamepad').__name__ == 'FocalGamepadConfig'\n"
        "heavy = ['mujoco', 'rtde_control', 'rtde_receive', 'pymodbus', 'pygame', 'pyrealsense2']\n"
        "print('HEAVY=' + ','.join(m for m in heavy if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "HEAVY=", f"imported at registration: {out.stdout}"
