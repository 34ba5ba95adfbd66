"""``--env.type=focal_adroit``: Adroit Hammer, Door and Pen with DP3 point clouds and 24-d hand state."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from lerobot.envs.configs import EnvConfig

from lerobot_focal.config_errors import reports_config_errors

from .base import FocalSimEnvConfig
from .features import check_obs_type, env_features, resolve_names

if TYPE_CHECKING:  # the env module imports gymnasium_robotics and mujoco: only load it when an env is built
    from .adroit_env import FocalAdroitEnv

#: Short task name -> (gymnasium id, action dim). Action dims as in DP3.
ADROIT_TASKS: dict[str, tuple[str, int]] = {
    "hammer": ("AdroitHandHammer-v1", 26),
    "door": ("AdroitHandDoor-v1", 28),
    "pen": ("AdroitHandPen-v1", 24),
}
ADROIT_STATE_DIM = 24
ADROIT_DEPTH_SIZE = 192
#: DP3 renders hammer/door from a 'top' camera that gymnasium-robotics' models do not have; 'vil_camera'
#: exists in all three and is the one DP3 uses for pen.
DEFAULT_ADROIT_CAMERA = "vil_camera"
#: World-frame box over the hand and objects. Its floor sits 5 mm above the table top (z = 0): with the table
#: inside, 54-91 % of the 512 points landed on the bare table; without it they cover hand, tool and object.
DEFAULT_ADROIT_WORKSPACE_LOW: tuple[float, float, float] = (-0.5, -0.5, 0.005)
DEFAULT_ADROIT_WORKSPACE_HIGH: tuple[float, float, float] = (0.5, 0.5, 0.8)
TASK_DESCRIPTIONS: dict[str, str] = {
    "hammer": "Pick up the hammer and drive the nail into the board.",
    "door": "Undo the latch and swing the door open.",
    "pen": "Reorient the pen to match the target orientation.",
}


ADROIT_GROUPS: dict[str, list[str]] = {"all": list(ADROIT_TASKS)}


def _canonical_task(name: str) -> str:
    """Accept 'hammer', 'adroit-hammer' and gymnasium's 'AdroitHandHammer-v1'."""
    name = name.strip()
    for short, (gym_id, _) in ADROIT_TASKS.items():
        if name == gym_id:
            return short
    return name.lower().removeprefix("adroit-").removeprefix("adroit_")


@EnvConfig.register_subclass("focal_adroit")
@reports_config_errors("--env.type=focal_adroit")
@dataclass
class FocalAdroitEnvConfig(FocalSimEnvConfig):
    """``task``: hammer, door, pen, 'all', or a comma-separated list. One task per config for training."""

    task: str = "hammer"
    # Adroit's control rate: frame_skip 5 x timestep 2 ms.
    fps: int = 100
    camera_name: str = DEFAULT_ADROIT_CAMERA
    observation_width: int = 84
    observation_height: int = 84
    # 'vil_camera' sees the hand from afar: at 84x84 the hammer scene leaves only ~270 pixels in the workspace
    # (fewer than 512 distinct points); 192x192 gives >= 512 for all three tasks at 12-28 ms CPU per cloud.
    depth_width: int = ADROIT_DEPTH_SIZE
    depth_height: int = ADROIT_DEPTH_SIZE
    workspace_low: tuple[float, float, float] = DEFAULT_ADROIT_WORKSPACE_LOW
    workspace_high: tuple[float, float, float] = DEFAULT_ADROIT_WORKSPACE_HIGH
    terminate_on_success: bool = True
    # Exact DP3 FPS (no voxel grid): the cropped clouds are small here, and a 1 cm grid would merge the pen
    # and the fingers.
    voxel_size: float = 0.0

    EXTRA_GYM_FIELDS: ClassVar[tuple[str, ...]] = ("terminate_on_success",)

    def __post_init__(self) -> None:
        self.check_fields()
        check_obs_type(self.obs_type)
        requested = ",".join(_canonical_task(t) for t in self.task.split(",") if t.strip())
        self.tasks = resolve_names(requested, ADROIT_TASKS, ADROIT_GROUPS, "Adroit task")
        action_dims = {ADROIT_TASKS[t][1] for t in self.tasks}
        if len(action_dims) != 1:
            raise ValueError(
                f"tasks {self.tasks} have different action sizes {sorted(action_dims)}; evaluate them separately"
            )
        self.features = env_features(
            self.obs_type,
            action_dim=action_dims.pop(),
            state_dim=ADROIT_STATE_DIM,
            num_points=self.num_points,
            image_hw=(self.observation_height, self.observation_width),
        )

    def task_groups(self) -> dict[str, list[str]]:
        return {name: [name] for name in self.tasks}

    def env_class(self) -> type[FocalAdroitEnv]:
        from .adroit_env import FocalAdroitEnv

        return FocalAdroitEnv

    def canonical_task(self, task: str) -> str:
        return _canonical_task(task)
