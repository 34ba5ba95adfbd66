"""A small, fully local LeRobotDataset whose trajectories the policy can only predict by reading observations.

Each episode reaches one of `num_goals` goals along its own smooth curved path; the goal is visible in the
state (9-d), in the point cloud (a cluster of points at the goal) and in the camera image (a bright square).
Several distinct smooth modes selected by the observation is the smallest task on which "did the policy
learn anything" has a crisp answer, and it needs no simulator, no download and a few seconds to write.
Used by the tests and by the README's quick demo before a simulator is involved.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_focal.constants import OBS_POINTCLOUD

GOALS = np.array(
    [[0.6, 0.0, 0.2], [-0.6, 0.1, 0.3], [0.0, 0.6, 0.1], [0.1, -0.6, 0.4]], dtype=np.float32
)


@dataclass
class SyntheticSpec:
    num_episodes: int = 12
    episode_length: int = 40
    num_goals: int = 4
    num_points: int = 512
    with_pointcloud: bool = True
    with_image: bool = False
    image_size: int = 32
    fps: int = 10
    seed: int = 0


def _path(goal: np.ndarray, start: np.ndarray, length: int, goal_id: int) -> np.ndarray:
    """Positions along a smooth curve from start to goal; the bend direction depends on the goal."""
    s = np.linspace(0.0, 1.0, length + 1, dtype=np.float32)[:, None]
    ease = s * s * (3 - 2 * s)  # smoothstep: zero velocity at both ends
    bend_dir = np.roll(np.eye(3, dtype=np.float32)[goal_id % 3], 1)
    bend = 0.25 * np.sin(np.pi * s) * bend_dir * (1 if goal_id % 2 == 0 else -1)
    return start + (goal - start) * ease + bend


def _pointcloud(rng: np.random.Generator, goal: np.ndarray, pos: np.ndarray, n: int) -> np.ndarray:
    """A flat table, a cluster at the goal and a few points at the end effector."""
    n_goal, n_ee = n // 4, n // 8
    table = np.c_[rng.uniform(-1, 1, (n - n_goal - n_ee, 2)), np.zeros((n - n_goal - n_ee, 1))]
    cluster = goal + 0.03 * rng.standard_normal((n_goal, 3))
    ee = pos + 0.02 * rng.standard_normal((n_ee, 3))
    return np.concatenate([table, cluster, ee]).astype(np.float32)


def _image(goal: np.ndarray, pos: np.ndarray, size: int) -> np.ndarray:
    img = np.zeros((size, size, 3), dtype=np.uint8)

    def to_px(p: np.ndarray) -> tuple[int, int]:
        return tuple(int(np.clip((v + 1) / 2 * (size - 4), 0, size - 4)) for v in p[:2])  # type: ignore[return-value]

    gx, gy = to_px(goal)
    img[gy : gy + 4, gx : gx + 4, 0] = 255
    ex, ey = to_px(pos)
    img[ey : ey + 3, ex : ex + 3, 1] = 255
    return img


def features(spec: SyntheticSpec) -> dict:
    feats = {
        "observation.state": {"dtype": "float32", "shape": (9,), "names": None},
        "action": {"dtype": "float32", "shape": (3,), "names": ["x", "y", "z"]},
    }
    if spec.with_pointcloud:
        feats[OBS_POINTCLOUD] = {"dtype": "float32", "shape": (spec.num_points, 3), "names": None}
    if spec.with_image:
        s = spec.image_size
        feats["observation.images.front"] = {
            "dtype": "image", "shape": (s, s, 3), "names": ["height", "width", "channel"]
        }
    return feats


def episode_arrays(spec: SyntheticSpec, episode: int) -> dict[str, np.ndarray]:
    """The frames of one episode as arrays (T, ...); deterministic in (seed, episode)."""
    rng = np.random.default_rng([spec.seed, episode])
    goal_id = episode % spec.num_goals
    goal = GOALS[goal_id % len(GOALS)]
    start = (0.05 * rng.standard_normal(3)).astype(np.float32)
    pos = _path(goal, start, spec.episode_length, goal_id)
    t = spec.episode_length
    state = np.concatenate([pos[:t], np.repeat(goal[None], t, 0), pos[:t] - goal], axis=1).astype(np.float32)
    out = {"observation.state": state, "action": pos[1:].astype(np.float32)}
    if spec.with_pointcloud:
        out[OBS_POINTCLOUD] = np.stack([_pointcloud(rng, goal, p, spec.num_points) for p in pos[:t]])
    if spec.with_image:
        out["observation.images.front"] = np.stack([_image(goal, p, spec.image_size) for p in pos[:t]])
    return out


def write_synthetic_dataset(
    root: str | Path, spec: SyntheticSpec, repo_id: str = "local/focal_synthetic"
) -> LeRobotDataset:
    """Write `spec.num_episodes` episodes to `root` as a LeRobotDataset (images as PNG, no video encoding)."""
    ds = LeRobotDataset.create(repo_id=repo_id, fps=spec.fps, features=features(spec), root=root, use_videos=False)
    for ep in range(spec.num_episodes):
        arrays = episode_arrays(spec, ep)
        for i in range(spec.episode_length):
            frame = {k: v[i] for k, v in arrays.items()}
            frame["task"] = f"reach goal {ep % spec.num_goals}"
            ds.add_frame(frame)
        ds.save_episode()
    ds.finalize()
    return ds
