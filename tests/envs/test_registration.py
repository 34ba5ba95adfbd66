"""Importing the envs package registers the configs and loads no simulator."""

import subprocess
import sys

import pytest


def test_import_registers_configs_without_simulators():
    code = (
        "import sys, lerobot_focal.envs\n"
        "from lerobot.envs.configs import EnvConfig\n"
        "known = EnvConfig.get_known_choices()\n"
        "assert 'focal_metaworld' in known and 'focal_adroit' in known, sorted(known)\n"
        "heavy = [m for m in ('metaworld', 'mujoco', 'gymnasium_robotics', 'minari') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]


def test_metaworld_config_resolves_groups_and_names():
    from lerobot_focal.envs.focal_metaworld import METAWORLD_GROUPS, FocalMetaworldEnvConfig

    assert {k: len(v) for k, v in METAWORLD_GROUPS.items()} == {"easy": 28, "medium": 11, "hard": 6, "very_hard": 5}
    cfg = FocalMetaworldEnvConfig(task="medium,reach", obs_type="pointcloud")
    assert cfg.tasks_by_group["medium"] == METAWORLD_GROUPS["medium"]
    assert cfg.tasks_by_group["reach-v3"] == ["reach-v3"]
    assert cfg.features["pointcloud"].shape == (512, 3)
    assert cfg.features["agent_pos"].shape == (9,)
    assert cfg.features["action"].shape == (4,)
    assert "pixels" not in cfg.features
    with pytest.raises(ValueError, match="valid MetaWorld tasks"):
        FocalMetaworldEnvConfig(task="no-such-task")
    with pytest.raises(ValueError, match="valid obs types"):
        FocalMetaworldEnvConfig(obs_type="depth")


def test_adroit_config_action_dims():
    from lerobot_focal.envs.focal_adroit import FocalAdroitEnvConfig

    assert FocalAdroitEnvConfig(task="door").features["action"].shape == (28,)
    assert FocalAdroitEnvConfig(task="AdroitHandPen-v1", obs_type="state").features["action"].shape == (24,)
    with pytest.raises(ValueError, match="different action sizes"):
        FocalAdroitEnvConfig(task="all")
