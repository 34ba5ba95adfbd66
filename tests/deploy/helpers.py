"""Shared by the async-inference tests: the UR-10e twin's names and features, and a small focal checkpoint."""

import json
from pathlib import Path

import numpy as np
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.utils.constants import OBS_ENV_STATE, OBS_STATE

from lerobot_focal.policy import FocalConfig, FocalPolicy, make_focal_pre_post_processors

JOINTS = ["shoulder_pan.pos", "shoulder_lift.pos", "elbow.pos", "wrist_1.pos", "wrist_2.pos", "wrist_3.pos"]
TCP = [f"ee_{a}.pos" for a in ("x", "y", "z", "roll", "pitch", "yaw")]
STATE_NAMES = [*JOINTS, "gripper.pos"]  # the dataset's observation.state: joints + gripper
ENV_NAMES = TCP[:3]  # ... and its observation.environment_state: a pose (here the TCP's position)
ACTION_NAMES = ["ee_x.vel", "ee_y.vel", "ee_z.vel", "ee_roll.vel", "ee_pitch.vel", "ee_yaw.vel", "gripper.pos"]
CAMERA = (24, 32)


def robot_features() -> dict[str, dict]:
    """What LeRobot's robot_client sends as lerobot_features for the UR-10e twin (its observation features)."""
    from lerobot.async_inference.helpers import map_robot_keys_to_lerobot_features

    from lerobot_focal.robots.ur10e.config_ur10e import UR10eConfig
    from lerobot_focal.robots.ur10e.ur10e import UR10e

    robot = UR10e(UR10eConfig(backend="sim", sim_camera_height=CAMERA[0], sim_camera_width=CAMERA[1]))
    return map_robot_keys_to_lerobot_features(robot)


def raw_observation(step: int) -> dict:
    """One raw UR-10e observation as robot.get_observation() returns it (floats, RGB, uint16 depth)."""
    rng = np.random.default_rng(step)
    values = 0.1 * step + rng.uniform(-1, 1, 13)
    obs = {k: float(v) for k, v in zip([*JOINTS, *TCP, "gripper.pos"], values, strict=True)}
    obs["front"] = rng.integers(0, 255, (*CAMERA, 3), dtype=np.uint8)
    obs["front_depth"] = rng.integers(500, 2000, (*CAMERA, 1), dtype=np.uint16)
    obs["task"] = "move the arm"
    return obs


def dataset_features() -> dict[str, dict]:
    vec = lambda names: {"dtype": "float32", "shape": [len(names)], "names": names}  # noqa: E731
    return {"action": vec(ACTION_NAMES), OBS_STATE: vec(STATE_NAMES), OBS_ENV_STATE: vec(ENV_NAMES)}


def random_checkpoint(path: Path, env_names: list[str] = ENV_NAMES, policy_type: str = "focal") -> Path:
    """A random-weights checkpoint (state 7 + environment state 3 -> 7-d action; ``focal`` with deterministic
    chunks, or ``diffusion_fco`` with 3 DDIM steps) whose train_config.json names a dataset folder holding the
    feature names."""
    dataset = path.parent / "dataset"
    (dataset / "meta").mkdir(parents=True)
    features = {**dataset_features(), OBS_ENV_STATE: {"dtype": "float32", "shape": [3], "names": env_names}}
    (dataset / "meta" / "info.json").write_text(json.dumps({"features": features}))
    inputs = {OBS_STATE: PolicyFeature(FeatureType.STATE, (7,)), OBS_ENV_STATE: PolicyFeature(FeatureType.ENV, (3,))}
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (7,))}
    stats = {k: {"min": torch.full((d,), -2.0), "max": torch.full((d,), 2.0), "mean": torch.zeros(d),
                 "std": torch.ones(d)} for k, d in ((OBS_STATE, 7), (OBS_ENV_STATE, 3), ("action", 7))}
    torch.manual_seed(0)
    if policy_type == "focal":
        cfg = FocalConfig(device="cpu", down_dims=(16, 32), use_env_state=True, inference_noise_scale=0.0,
                          input_features=inputs, output_features=outputs)
        policy, (pre, post) = FocalPolicy(cfg), make_focal_pre_post_processors(cfg, dataset_stats=stats)
    else:
        from lerobot_focal.policy.diffusion_fco import DiffusionFcoConfig, DiffusionFcoPolicy
        from lerobot_focal.policy.diffusion_fco.processor_diffusion_fco import make_diffusion_fco_pre_post_processors

        cfg = DiffusionFcoConfig(device="cpu", input_features=inputs, output_features=outputs, horizon=16,
                                 n_obs_steps=2, n_action_steps=4, down_dims=(16, 32), kernel_size=3, n_groups=4,
                                 diffusion_step_embed_dim=16, noise_scheduler_type="DDIM", num_inference_steps=3)
        policy = DiffusionFcoPolicy(cfg)
        pre, post = make_diffusion_fco_pre_post_processors(cfg, dataset_stats=stats)
    for part in (policy, pre, post):
        part.save_pretrained(path)
    (path / "train_config.json").write_text(json.dumps({"dataset": {"repo_id": "local/x", "root": str(dataset)}}))
    return path
