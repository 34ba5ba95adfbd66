"""``--env.type=focal_metaworld``: every MetaWorld v3 task with DP3 point clouds and 9-d state."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from lerobot.envs.configs import EnvConfig

from lerobot_focal.config_errors import reports_config_errors, require_non_negative

from .base import FocalSimEnvConfig
from .features import DEFAULT_VOXEL_SIZE, check_obs_type, env_features, resolve_names, uses_pixels

if TYPE_CHECKING:  # the env module imports metaworld and mujoco: only load it when an env is built
    from .metaworld_env import FocalMetaworldEnv

METAWORLD_STATE_DIM = 9
METAWORLD_ACTION_DIM = 4
#: MetaWorld v3's own observation: hand, gripper, two object poses, the previous frame of those, goal.
METAWORLD_ENV_STATE_DIM = 39
#: DP3 moves camera ``corner2`` here; LeRobot's own metaworld env uses another position.
DP3_CORNER2_POS: tuple[float, float, float] = (0.6, 0.295, 0.8)
#: World-frame box around the objects and the arm, inside the table's 12 cm retaining rim (front face at
#: y = 0.22, back at 0.98, sides at |x| = 0.68): drops floor, rim, back walls and background. Static scenery
#: carries nothing a policy can use, and farthest-point sampling spreads the 512 points over it evenly: with
#: the rim and the table top inside the box they took 79-87 % of the points and left 4-5 within 4 cm of the
#: object, against 12-36 without them (`lerobot-focal-bench cloud-content`, five tasks).
DEFAULT_WORKSPACE_LOW: tuple[float, float, float] = (-0.6, 0.23, -0.02)
DEFAULT_WORKSPACE_HIGH: tuple[float, float, float] = (0.6, 0.97, 0.75)
#: Points closer than this (m) above the table top are cropped away, as DP3 crops the table out of its clouds.
DEFAULT_TABLE_CLEARANCE = 0.005


def _load_lerobot_metaworld_config() -> dict[str, Any]:
    """LeRobot's task table, read as data: ``lerobot.envs.metaworld`` itself imports metaworld."""
    return json.loads((resources.files("lerobot.envs") / "metaworld_config.json").read_text())


_MW_CONFIG = _load_lerobot_metaworld_config()
#: Task -> language description, as LeRobot ships it.
TASK_DESCRIPTIONS: dict[str, str] = dict(_MW_CONFIG["TASK_DESCRIPTIONS"])
#: The 50 MetaWorld v3 task names LeRobot ships (lerobot/envs/metaworld_config.json).
METAWORLD_TASKS: tuple[str, ...] = tuple(sorted(TASK_DESCRIPTIONS))
#: The difficulty split of Seo et al. used by DP3/FlowPolicy/FocalPolicy, as LeRobot ships it.
METAWORLD_GROUPS: dict[str, list[str]] = {k: list(v) for k, v in _MW_CONFIG["DIFFICULTY_TO_TASKS"].items()}


def _canonical_task(name: str) -> str:
    """Accept 'pick-place', 'pick-place-v3' and LeRobot's 'metaworld-pick-place-v3' spellings."""
    name = name.strip().removeprefix("metaworld-")
    if name in METAWORLD_GROUPS or name.endswith("-v3"):
        return name
    return f"{name}-v3" if f"{name}-v3" in TASK_DESCRIPTIONS else name


def resolve_metaworld_tasks(task: str) -> dict[str, list[str]]:
    """'easy,pick-place' -> {'easy': [...28 tasks], 'pick-place-v3': ['pick-place-v3']} (eval groups)."""
    out: dict[str, list[str]] = {}
    for item in (t for t in task.split(",") if t.strip()):
        canonical = _canonical_task(item)
        out[canonical] = resolve_names(canonical, METAWORLD_TASKS, METAWORLD_GROUPS, "MetaWorld task")
    if not out:
        resolve_names("", METAWORLD_TASKS, METAWORLD_GROUPS, "MetaWorld task")  # raises with the valid list
    return out


def recorded_seeded_episodes(path: str | Path) -> int:
    """Episodes with a reset seed in an env's metrics file (autoreset episodes, seedless, are not evaluations)."""
    path = Path(path)
    if not path.exists():
        return 0
    count = 0
    for line in path.read_text().splitlines():
        try:
            count += json.loads(line).get("seed") is not None
        except json.JSONDecodeError:  # a line torn by an interruption
            continue
    return count


@EnvConfig.register_subclass("focal_metaworld")
@reports_config_errors("--env.type=focal_metaworld")
@dataclass
class FocalMetaworldEnvConfig(FocalSimEnvConfig):
    """``task``: a v3 task, a difficulty group (easy, medium, hard, very_hard) or a comma-separated mix."""

    task: str = "pick-place-v3"
    # MetaWorld's control rate: frame_skip 5 x timestep 2.5 ms.
    fps: int = 80
    # Also emit MetaWorld's 39-d observation (object poses) as observation.environment_state. It is what
    # LeRobot's `diffusion` needs without images, so the CPU benchmark gives every method the same input.
    env_state: bool = False
    render_mode: str = "rgb_array"
    camera_name: str = "corner2"
    camera_pos: tuple[float, float, float] | None = DP3_CORNER2_POS
    workspace_low: tuple[float, float, float] = DEFAULT_WORKSPACE_LOW
    workspace_high: tuple[float, float, float] = DEFAULT_WORKSPACE_HIGH
    voxel_size: float = DEFAULT_VOXEL_SIZE
    # Crop the table out of the cloud: the box's lower z is raised to this far above the task's own table top
    # (sweep-into's is 5 cm higher than the others'). None keeps the table in the cloud.
    table_clearance: float | None = DEFAULT_TABLE_CLEARANCE
    # False: render() (videos only, never observations) returns a blank 16x16 frame. `lerobot-train` renders
    # every env of 4 evaluation episodes to video at each evaluation (hard-coded); with software OpenGL that was
    # ~70 % of a benchmark run's time. The benchmark grid turns it off; simulation and metrics are unchanged.
    render_videos: bool = True
    multitask_eval: bool = True
    # Fresh placements at every evaluation, as DP3's runner draws them: None = LeRobot's reset seeds as given
    # (`lerobot-train` resets each evaluation with the same seeds --seed … --seed + N − 1). Set, each set of envs
    # built for an evaluation adds this plus the number of evaluation episodes already recorded in
    # ``metrics_path`` to every reset seed, so evaluation i of a run uses seeds fresh_reset_seeds + i·N + --seed …;
    # the count comes from the file (not a counter in the process) so that a run resumed from a checkpoint, whose
    # file the grid cuts back to that checkpoint, continues with new placements instead of replaying the first.
    fresh_reset_seeds: int | None = None
    # A diagnostic of execution, not a policy setting: the gripper command (action[3]) is snapped to the nearer of
    # these two levels before it reaches MetaWorld (the two levels the scripted expert's demos use, e.g. 0 and 1 for
    # pick-place), so a policy's hesitant in-between grip commands can be told apart from its arm motion. The ATV
    # and the recorded actions are those after snapping. None: actions as the policy gives them.
    gripper_levels: tuple[float, float] | None = None

    EXTRA_GYM_FIELDS: ClassVar[tuple[str, ...]] = (
        "env_state", "camera_pos", "render_videos", "table_clearance", "gripper_levels",
    )

    def __post_init__(self) -> None:
        self.check_fields()
        check_obs_type(self.obs_type)
        require_non_negative(table_clearance=self.table_clearance, fresh_reset_seeds=self.fresh_reset_seeds)
        if self.fresh_reset_seeds is not None and not self.metrics_path:
            raise ValueError(
                "fresh_reset_seeds counts the evaluation episodes recorded in metrics_path: set --env.metrics_path "
                "too (or leave fresh_reset_seeds unset)."
            )
        if self.gripper_levels is not None:
            levels = tuple(float(x) for x in self.gripper_levels)
            if len(levels) != 2 or not all(math.isfinite(x) for x in levels) or levels[0] == levels[1]:
                raise ValueError(
                    f"gripper_levels must be two different finite numbers (the demos' open and closed commands, "
                    f"e.g. --env.gripper_levels='[0.0,1.0]'); got {self.gripper_levels!r}"
                )
            self.gripper_levels = levels
        if self.render_mode != "rgb_array":
            raise ValueError(f"render_mode must be 'rgb_array' (frames for videos), got {self.render_mode!r}.")
        if not self.render_videos and uses_pixels(self.obs_type):
            raise ValueError(
                f"render_videos=false blanks rendered frames, but obs_type={self.obs_type!r} observes pixels: "
                "keep render_videos=true or use obs_type state/pointcloud"
            )
        self.tasks_by_group = resolve_metaworld_tasks(self.task)
        self.features = env_features(
            self.obs_type,
            action_dim=METAWORLD_ACTION_DIM,
            state_dim=METAWORLD_STATE_DIM,
            num_points=self.num_points,
            image_hw=(self.observation_height, self.observation_width),
            env_state_dim=METAWORLD_ENV_STATE_DIM if self.env_state else None,
        )

    def task_groups(self) -> dict[str, list[str]]:
        return self.tasks_by_group

    def _env_factory(self, task: str):
        if self.fresh_reset_seeds is None:
            return super()._env_factory(task)
        offset = self.fresh_reset_seeds + recorded_seeded_episodes(self.metrics_path)
        cls, kwargs = self.env_class(), {**self.gym_kwargs, "reset_seed_offset": offset}
        return lambda: cls(task=task, **kwargs)

    def env_class(self) -> type[FocalMetaworldEnv]:
        from .metaworld_env import FocalMetaworldEnv

        return FocalMetaworldEnv

    def canonical_task(self, task: str) -> str:
        (name,) = resolve_names(_canonical_task(task), METAWORLD_TASKS, {}, "MetaWorld task")
        return name
