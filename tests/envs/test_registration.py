"""Importing the envs package registers the configs and loads no simulator."""

import subprocess
import sys

import numpy as np
import pytest

from lerobot_focal.config_errors import ConfigError


@pytest.mark.subprocess
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
    with pytest.raises(ConfigError, match="valid MetaWorld tasks"):
        FocalMetaworldEnvConfig(task="no-such-task")
    with pytest.raises(ConfigError, match="valid obs types"):
        FocalMetaworldEnvConfig(obs_type="depth")


def test_adroit_config_action_dims():
    from lerobot_focal.envs.focal_adroit import FocalAdroitEnvConfig

    assert FocalAdroitEnvConfig(task="door").features["action"].shape == (28,)
    assert FocalAdroitEnvConfig(task="AdroitHandPen-v1", obs_type="state").features["action"].shape == (24,)
    with pytest.raises(ConfigError, match="different action sizes"):
        FocalAdroitEnvConfig(task="all")


@pytest.mark.subprocess
def test_lerobots_lazy_async_vector_env_is_what_the_envs_expect():
    """Async evaluation uses LeRobot's private `_LazyAsyncVectorEnv` (lerobot_focal/envs/vector.py says why). If
    LeRobot renames it or changes its constructor or laziness, this fails here, not in a user's lerobot-eval."""
    import inspect

    pytest.importorskip("metaworld")
    from lerobot.envs.utils import _LazyAsyncVectorEnv

    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    params = list(inspect.signature(_LazyAsyncVectorEnv.__init__).parameters)
    assert params[:5] == ["self", "env_fns", "observation_space", "action_space", "metadata"], params
    envs = FocalMetaworldEnvConfig(task="reach,push", obs_type="state").create_envs(2, use_async_envs=True)
    reach, push = envs["reach-v3"][0], envs["push-v3"][0]
    assert isinstance(reach, _LazyAsyncVectorEnv) and reach._env is None and push._env is None  # no workers yet
    assert push.observation_space == reach.observation_space  # the second task reused the first one's spaces
    try:
        obs, _ = reach.reset(seed=[0, 1])
        assert obs["agent_pos"].shape == (2, 9) and push._env is None
    finally:
        reach.close()
        push.close()


def test_lerobots_metaworld_env_still_calls_the_hooks_focal_overrides():
    """FocalMetaworldEnv overrides LeRobot's private `_ensure_env` / `_format_raw_obs`; if LeRobot's reset stops
    calling them, our observations would silently be LeRobot's. This fails first."""
    import inspect

    pytest.importorskip("metaworld")
    from lerobot.envs.metaworld import MetaworldEnv

    reset = inspect.getsource(MetaworldEnv.reset)
    assert "self._ensure_env()" in reset and "self._format_raw_obs(" in reset
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    env = FocalMetaworldEnvConfig(task="push", obs_type="state", env_state=True).make_single_env()
    try:
        a, _ = env.reset(seed=0)
        b, _ = env.reset(seed=1)
        assert set(a) == {"agent_pos", "environment_state"}  # our formatting, not LeRobot's
        # MetaWorld's _freeze_rand_vec is off: the seed moves the object.
        assert not np.allclose(a["environment_state"][4:7], b["environment_state"][4:7])
    finally:
        env.close()


def test_gymnasiums_private_viewer_hook_used_for_cheap_rendering_is_there():
    """`sim.rendering.make_rendering_cheap` reaches the offscreen viewer through gymnasium's private
    `MujocoRenderer._get_viewer(render_mode=...)`; a rename in gymnasium must fail here, not in a user's eval."""
    import inspect

    pytest.importorskip("mujoco")
    from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

    assert "render_mode" in inspect.signature(MujocoRenderer._get_viewer).parameters
