"""The rtde backend without a controller: the install hint, camera calibration checks, pose conversions.

Everything that talks to a controller is tested against the emulated one (test_ur10e_rtde_emulator.py,
test_ur10e_rtde_driver.py), through the real ur_rtde client.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from lerobot_focal.config_errors import ConfigError
from lerobot_focal.robots.ur10e import UR10e, UR10eConfig
from lerobot_focal.robots.ur10e.kinematics import pose6_from_rotvec_pose, rotvec_pose_from_pose6


def test_missing_ur_rtde_names_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "rtde_control", None)  # makes `import rtde_control` raise ImportError
    robot = UR10e(UR10eConfig(backend="rtde", calibration_dir=tmp_path))
    assert "ee_x.pos" in robot.observation_features  # features still work without the package
    with pytest.raises(ImportError, match=r"lerobot_policy_focal\[robot\]"):
        robot.connect()


def test_real_cameras_need_a_hand_eye_pose():
    from lerobot.cameras.realsense import RealSenseCameraConfig

    cam = RealSenseCameraConfig(serial_number_or_name="123", fps=30, width=640, height=480, use_depth=True)
    with pytest.raises(ConfigError, match="camera_poses"):
        UR10eConfig(backend="rtde", cameras={"front": cam})
    cfg = UR10eConfig(backend="rtde", cameras={"front": cam}, camera_poses={"front": [0, 0, 1, 0, 0, 0]})
    feats = UR10e(cfg).observation_features
    assert feats["front"] == (480, 640, 3) and feats["front_depth"] == (480, 640, 1)


def test_ur_rotvec_round_trip():
    pose = np.array([-0.6, -0.17, 0.4, 0.1, -0.2, 0.3])
    np.testing.assert_allclose(pose6_from_rotvec_pose(rotvec_pose_from_pose6(pose)), pose, atol=1e-9)
    # tool pointing straight down is UR's [.., pi, 0, 0] rotation vector and our zero orientation
    np.testing.assert_allclose(pose6_from_rotvec_pose([0, 0, 0, np.pi, 0, 0])[3:], 0.0, atol=1e-9)
