"""A bad value for any config the plugin registers stops the real command at parse time with that config's own
message (what was wrong, the valid values), not draccus's "Couldn't instantiate class ..." and two tracebacks.

FocalConfig's own fields are covered in tests/policy/test_cli_config_errors.py; here every other registered
config, each through the command a user would type it into. Each call only parses its arguments: nothing
connects to a robot or a gamepad, and nothing trains.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from lerobot_focal.datasets.making.synthetic import SyntheticSpec, write_synthetic_dataset

from .cli import assert_config_error, run_lerobot

pytestmark = pytest.mark.subprocess  # each refusal through the real LeRobot command


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("cfg") / "dataset"
    write_synthetic_dataset(root, SyntheticSpec(num_episodes=2, episode_length=16, num_points=16))
    return root


EVAL = ["--policy.path=/nonexistent/checkpoint"]  # never reached: the env config fails first
TELEOP = ["--teleop.type=focal_gamepad"]
RECORD = ["--dataset.repo_id=local/never_written", "--dataset.single_task=never recorded"]

CASES = {
    "metaworld-task": (
        "lerobot-eval", ["--env.type=focal_metaworld", "--env.task=nope", *EVAL],
        "--env.type=focal_metaworld: unknown MetaWorld task 'nope'. Valid groups: easy", "FocalMetaworldEnvConfig",
    ),
    "metaworld-box": (
        "lerobot-eval",
        ["--env.type=focal_metaworld", "--env.workspace_low=[0,0,0]", "--env.workspace_high=[1,1,0]", *EVAL],
        "workspace_low (0.0, 0.0, 0.0) must be below workspace_high (1.0, 1.0, 0.0)", "FocalMetaworldEnvConfig",
    ),
    "adroit-points": (
        "lerobot-eval", ["--env.type=focal_adroit", "--env.num_points=0", *EVAL],
        "--env.type=focal_adroit: num_points must be a number > 0, got 0.", "FocalAdroitEnvConfig",
    ),
    "ur10e-backend-teleoperate": (
        "lerobot-teleoperate", ["--robot.type=ur10e", "--robot.backend=nope", *TELEOP],
        "--robot.type=ur10e: backend must be one of ['sim', 'rtde'], got 'nope'.", "UR10eConfig",
    ),
    "ur10e-speed-record": (
        "lerobot-record", ["--robot.type=ur10e", "--robot.safety.max_linear_speed=-0.1", *TELEOP, *RECORD],
        "--robot.type=ur10e: safety.max_linear_speed must be a number > 0, got -0.1.", "UR10eConfig",
    ),
    # lerobot-record's teleop is optional, so draccus lists the message under the type it tried.
    "gamepad-threshold-record": (
        "lerobot-record", ["--robot.type=ur10e", *TELEOP, "--teleop.trigger_threshold=2", *RECORD],
        "--teleop.type=focal_gamepad: trigger_threshold must be in (0.0, 1.0), got 2.0.", "FocalGamepadConfig",
    ),
    "gamepad-speed-teleoperate": (
        "lerobot-teleoperate", ["--robot.type=ur10e", *TELEOP, "--teleop.max_angular_speed=0"],
        "--teleop.type=focal_gamepad: max_angular_speed must be a number > 0, got 0.0.", "FocalGamepadConfig",
    ),
}
TRAIN_CASES = {
    "diffusion_fco-lambda": (
        ["--policy.type=diffusion_fco", "--policy.fco_lambda=-1"],
        "--policy.type=diffusion_fco: fco_lambda must be a number ≥ 0, got -1.0.", "DiffusionFcoConfig",
    ),
    "diffusion_fco-lerobot-field": (  # LeRobot's own DiffusionConfig checks reach the user the same way
        ["--policy.type=diffusion_fco", "--policy.noise_scheduler_type=nope"],
        "`noise_scheduler_type` must be one of ['DDPM', 'DDIM']. Got nope.", "DiffusionFcoConfig",
    ),
    "focal_adamw-lr": (
        ["--policy.type=focal", "--use_policy_training_preset=false", "--optimizer.type=focal_adamw",
         "--optimizer.lr=-1", "--scheduler.type=cosine_decay_with_warmup"],
        "--optimizer.type=focal_adamw: lr must be a number > 0, got -1.0.", "FusedAdamWConfig",
    ),
    # lerobot-train's env is optional: draccus lists the message under the type it tried.
    "metaworld-in-train": (
        ["--policy.type=focal", "--env.type=focal_metaworld", "--env.episode_length=0"],
        "--env.type=focal_metaworld: episode_length must be a number > 0, got 0.", "FocalMetaworldEnvConfig",
    ),
}


# Each case starts a LeRobot command (~13 s of imports on 2 cores). The default suite keeps one refusal per
# command and config class; the other cases, whose messages tests/test_config_errors.py checks in process, run
# with `pytest -m slow`.
SLOW_CASES = {"metaworld-box", "gamepad-speed-teleoperate", "diffusion_fco-lambda"}


def _cases(names) -> list:
    return [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_CASES else n for n in names]


@pytest.mark.parametrize("case", _cases(CASES))
def test_bad_env_robot_or_teleop_value_reaches_the_user(case, tmp_path):
    command, args, message, config_class = CASES[case]
    proc = run_lerobot(command, *args, cwd=tmp_path, timeout=300)
    assert_config_error(proc, message, config_class)
    assert not any(tmp_path.iterdir()), "the command wrote something despite the bad value"


@pytest.mark.parametrize("case", _cases(TRAIN_CASES))
def test_bad_value_of_another_plugin_config_stops_lerobot_train(case, dataset, tmp_path):
    args, message, config_class = TRAIN_CASES[case]
    proc = run_lerobot(
        "lerobot-train", *args, "--dataset.repo_id=local/focal_synthetic", f"--dataset.root={dataset}",
        "--policy.push_to_hub=false", f"--output_dir={tmp_path / 'run'}", "--steps=1", cwd=tmp_path, timeout=300,
    )
    assert_config_error(proc, message, config_class)
    assert not (tmp_path / "run").exists(), "training started despite the bad value"
