"""Every impossible value of every registered config is refused when the config is built, naming the field;
the error is a draccus DecodingError (what reaches a CLI user verbatim), never a ValueError (which draccus
hides). The CLI side is tests/test_cli_config_errors.py; this is the field-by-field sweep, in process."""

from __future__ import annotations

import re
from dataclasses import dataclass

import pytest
from draccus.utils import DecodingError

from lerobot_focal.config_errors import ConfigError, reports_config_errors
from lerobot_focal.envs.focal_adroit import FocalAdroitEnvConfig
from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig
from lerobot_focal.policy import FocalConfig, FocalConfigError
from lerobot_focal.policy.depth_cloud_settings import DepthCloudConfig
from lerobot_focal.policy.diffusion_fco import DiffusionFcoConfig
from lerobot_focal.policy.method_groups import AnchorConfig, LossConfig
from lerobot_focal.policy.optimizer import FusedAdamWConfig
from lerobot_focal.robots.ur10e import UR10eConfig
from lerobot_focal.robots.ur10e.safety import SafetyConfig
from lerobot_focal.teleoperators.focal_gamepad.config_focal_gamepad import FocalGamepadConfig, GamepadMapping


def test_decorator_prefixes_the_label_and_is_no_value_error():
    @reports_config_errors("--thing.type=demo")
    @dataclass
    class Demo:
        size: int = 1

        def __post_init__(self) -> None:
            if self.size < 1:
                raise ValueError(f"size must be ≥ 1, got {self.size}.")

    Demo()
    with pytest.raises(ConfigError) as info:
        Demo(size=0)
    assert str(info.value) == "--thing.type=demo: size must be ≥ 1, got 0."
    assert isinstance(info.value, DecodingError) and not isinstance(info.value, ValueError)


FOCAL_BAD = {
    "loss.freq_weight": dict(loss=LossConfig(freq_weight=-1.0)),
    "loss.time_weight": dict(loss=LossConfig(time_weight=-0.5)),
    "loss.macro_mse_weight": dict(loss=LossConfig(regularizer="time_mse", macro_mse_weight=-1.0)),
    "loss.cfm_alpha": dict(loss=LossConfig(cfm_alpha=-1e-5)),
    "every term of the FCO loss has weight 0": dict(loss=LossConfig(time_weight=0.0, freq_weight=0.0)),
    "ema_power": dict(ema_power=0.0),
    "ema_max_decay > 0": dict(ema_max_decay=0.0),
    "loss.freq_cutoff must be in (0, 4)": dict(loss=LossConfig(freq_band="low", freq_window="proximal",
                                                                freq_cutoff=4)),
    "anchor.eps": dict(anchor=AnchorConfig(eps=1.0)),
    "anchor.sigma": dict(anchor=AnchorConfig(sigma=-1.6)),
    "anchor.mu": dict(anchor=AnchorConfig(mu=float("nan"))),
    "anchor.fixed_r": dict(anchor=AnchorConfig(kind="fixed", fixed_r=1.5)),
    "anchor.adjacent_delta": dict(anchor=AnchorConfig(adjacent_delta=0.0)),
    "anchor.mixture_ratio": dict(anchor=AnchorConfig(mixture_ratio=-0.1)),
    "loss.cfm_boundary": dict(loss=LossConfig(cfm_boundary=0.0)),
    "kernel_size": dict(kernel_size=4),
    "n_groups": dict(n_groups=5),
    "time_embed_dim": dict(time_embed_dim=7),
    "down_dims": dict(down_dims=()),
    "time_scale": dict(time_scale=0.0),
    "pointcloud_feature_dim": dict(pointcloud_feature_dim=0),
    "state_feature_dim": dict(state_feature_dim=-64),
    "depth_cloud.num_points": dict(depth_cloud=DepthCloudConfig(num_points=0)),
    "depth_cloud.voxel_size": dict(depth_cloud=DepthCloudConfig(voxel_size=-0.01)),
    "crop_shape": dict(crop_shape=(0, 84)),
    "vision_backbone": dict(vision_backbone="vit_b_16"),
    "use_group_norm=false": dict(pretrained_backbone_weights="ResNet18_Weights.IMAGENET1K_V1"),
    "drop_n_last_frames": dict(drop_n_last_frames=-1),
    "optimizer_lr": dict(optimizer_lr=0.0),
    "optimizer_betas[0]": dict(optimizer_betas=(1.0, 0.999)),
    "optimizer_eps": dict(optimizer_eps=0.0),
    "optimizer_weight_decay": dict(optimizer_weight_decay=-1e-6),
    "optimizer_grad_clip_norm": dict(optimizer_grad_clip_norm=0.0),
    "scheduler_name": dict(scheduler_name="exponential"),
    "scheduler_warmup_steps": dict(scheduler_warmup_steps=-1),
}


@pytest.mark.parametrize("field", list(FOCAL_BAD))
def test_focal_config_refuses_impossible_values(field):
    with pytest.raises(FocalConfigError, match=r"^--policy\.type=focal: .*" + re.escape(field)):
        FocalConfig(device="cpu", **FOCAL_BAD[field])


OTHER_BAD = [
    (FocalMetaworldEnvConfig, dict(depth_width=0), "--env.type=focal_metaworld: depth_width"),
    (FocalMetaworldEnvConfig, dict(voxel_size=-0.01), "voxel_size"),
    (FocalMetaworldEnvConfig, dict(raycast_threads=0), "raycast_threads"),
    (FocalMetaworldEnvConfig, dict(table_clearance=-0.01), "table_clearance"),
    (FocalMetaworldEnvConfig, dict(fresh_reset_seeds=-1, metrics_path="m.jsonl"), "fresh_reset_seeds"),
    (FocalMetaworldEnvConfig, dict(fresh_reset_seeds=0), "set --env.metrics_path too"),
    (FocalMetaworldEnvConfig, dict(render_mode="human"), "render_mode"),
    (FocalAdroitEnvConfig, dict(episode_length=-5), "--env.type=focal_adroit: episode_length"),
    (FocalAdroitEnvConfig, dict(workspace_low=(0.0, 0.0, 0.5), workspace_high=(1.0, 1.0, 0.5)), "workspace_low"),
    (UR10eConfig, dict(gripper="robotiq"), "--robot.type=ur10e: gripper must be one of"),
    (UR10eConfig, dict(rtde_frequency=0.0), "rtde_frequency"),
    (UR10eConfig, dict(rtde_timeout_s=-1.0), "rtde_timeout_s"),
    (UR10eConfig, dict(servo_lookahead_s=0.5), "servo_lookahead_s must be in \\[0.03, 0.2\\]"),
    (UR10eConfig, dict(servo_gain=50.0), "servo_gain"),
    (UR10eConfig, dict(sim_camera_fovy_deg=180.0), "sim_camera_fovy_deg"),
    (UR10eConfig, dict(sim_joint_speed_fraction=1.5), "sim_joint_speed_fraction"),
    (UR10eConfig, dict(sim_camera_width=0), "sim_camera_width"),
    (UR10eConfig, dict(tcp_offset=float("nan")), "tcp_offset"),
    (UR10eConfig, dict(safety=SafetyConfig(max_angular_speed=0.0)), "safety.max_angular_speed"),
    (UR10eConfig, dict(safety=SafetyConfig(workspace_min=(0, 0, 1), workspace_max=(1, 1, 0))), "safety.workspace_min"),
    (UR10eConfig, dict(camera_poses={"front": [0.0, 0.0, 1.0]}), "camera_poses"),
    (UR10eConfig, dict(sim_camera_pos=(0.0, 0.0, 1.0), sim_camera_lookat=(0.0, 0.0, 1.0)), "same point"),
    (FocalGamepadConfig, dict(max_linear_speed=0.0), "--teleop.type=focal_gamepad: max_linear_speed"),
    (FocalGamepadConfig, dict(gripper_step=0.0), "gripper_step"),
    (FocalGamepadConfig, dict(trigger_threshold=1.0), "trigger_threshold"),
    (FocalGamepadConfig, dict(signs=[1.0, 1.0, 0.0, 1.0, 1.0, 1.0]), "signs"),
    (FocalGamepadConfig, dict(joystick_index=-1), "joystick_index"),
    (FocalGamepadConfig, dict(mapping=GamepadMapping(deadman_button=-1)), "deadman_button"),
    (FocalGamepadConfig, dict(speed_levels=[0.5, float("inf")]), "speed_levels"),
    (DiffusionFcoConfig, dict(fco_time_weight=-1.0), "--policy.type=diffusion_fco: fco_time_weight"),
    (DiffusionFcoConfig, dict(fco_lambda=-1.0), "--policy.type=diffusion_fco: fco_lambda must be a number ≥ 0"),
    (DiffusionFcoConfig, dict(fco_keep_diffusion_loss=False, fco_lambda=0.0, fco_time_weight=0.0),
     "nothing would train"),
    (FusedAdamWConfig, dict(betas=(0.9,)), "--optimizer.type=focal_adamw: betas must be two numbers"),
    (FusedAdamWConfig, dict(weight_decay=-0.01), "weight_decay"),
]


@pytest.mark.parametrize(("cls", "kwargs", "message"), OTHER_BAD,
                         ids=[f"{c.__name__}-{next(iter(k))}" for c, k, _ in OTHER_BAD])
def test_other_configs_refuse_impossible_values(cls, kwargs, message):
    with pytest.raises(ConfigError, match=message):
        cls(**kwargs)


def test_defaults_are_valid():
    for cls in (FocalMetaworldEnvConfig, FocalAdroitEnvConfig, UR10eConfig, FocalGamepadConfig, DiffusionFcoConfig,
                FusedAdamWConfig):
        cls()
    FocalConfig(device="cpu")

