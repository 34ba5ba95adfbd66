"""Import Adroit demonstrations from a local Minari dataset into a LeRobotDataset with focal observations.

    python -m lerobot_focal.datasets.making.minari_import --dataset_id adroit/door/expert-v0 --root data/adroit_door

Minari stores gymnasium-robotics' own observation vector and the actions, not point clouds or camera frames.
Each episode is therefore *replayed* in ``focal_adroit``'s simulator from its recorded reset seed, and the
observations ``focal`` uses (24-d hand state, 512-point cloud, optional RGB) are rendered along the way. The
replay is checked against the stored observations step by step: an episode whose replay drifts further than
``--max_drift`` (the recording came from another simulator version, or from states the seed cannot recreate)
is skipped with a warning rather than written with observations that do not match its actions.

By default only episodes whose replay reaches the task's success are kept (``--all_episodes`` keeps all).
Datasets stored in Minari's arrow format need only ``minari``; its HDF5 format also needs ``h5py``.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_focal.console import doc_parser
from lerobot_focal.constants import OBS_POINTCLOUD


@dataclass
class ImportConfig:
    dataset_id: str
    root: Path
    task: str | None = None
    repo_id: str = "local/focal_adroit"
    obs_types: tuple[str, ...] = ("pointcloud",)
    only_successful: bool = True
    max_drift: float = 1e-3
    max_episodes: int | None = None
    minari_root: str | None = None


def _infer_task(dataset, requested: str | None) -> str:
    from lerobot_focal.envs.focal_adroit import ADROIT_TASKS

    if requested:
        return requested
    env_id = dataset.spec.env_spec.id if dataset.spec.env_spec is not None else None
    for short, (gym_id, _) in ADROIT_TASKS.items():
        if env_id == gym_id:
            return short
    raise SystemExit(f"cannot tell the Adroit task of Minari env {env_id!r}; pass --task hammer|door|pen")


def _features(obs_types, action_dim: int, num_points: int, image_hw: tuple[int, int]) -> dict:
    from lerobot_focal.envs.focal_adroit import ADROIT_STATE_DIM

    features = {
        "action": {"dtype": "float32", "shape": (action_dim,), "names": None},
        "observation.state": {"dtype": "float32", "shape": (ADROIT_STATE_DIM,), "names": None},
    }
    if "pointcloud" in obs_types:
        features[OBS_POINTCLOUD] = {"dtype": "float32", "shape": (num_points, 3), "names": ["points", "xyz"]}
    if "pixels" in obs_types:
        features["observation.image"] = {
            "dtype": "image", "shape": (*image_hw, 3), "names": ["height", "width", "channels"]
        }
    return features


def replay_episode(env, seed: int, actions: np.ndarray, stored_obs: np.ndarray | None, want_pixels: bool):
    """Replay one episode; returns (frames, success, max_drift)."""
    obs, _ = env.reset(seed=seed)
    drift = 0.0 if stored_obs is None else float(np.abs(env.last_raw_obs - stored_obs[0]).max())
    frames, success = [], False
    for t, action in enumerate(actions):
        frame = {"observation.state": obs["agent_pos"], "action": np.asarray(action, dtype=np.float32)}
        if "pointcloud" in obs:
            frame[OBS_POINTCLOUD] = obs["pointcloud"]
        if want_pixels:
            frame["observation.image"] = obs["pixels"]
        frames.append(frame)
        obs, _, _, _, info = env.step(np.asarray(action, dtype=np.float32))
        success |= bool(info["is_success"])
        if stored_obs is not None and t + 1 < len(stored_obs):
            drift = max(drift, float(np.abs(env.last_raw_obs - stored_obs[t + 1]).max()))
    return frames, success, drift


def import_minari(cfg: ImportConfig) -> dict:
    import minari
    from lerobot.datasets import LeRobotDataset
    from tqdm import tqdm

    from lerobot_focal.envs.focal_adroit import ADROIT_TASKS, TASK_DESCRIPTIONS, FocalAdroitEnvConfig

    if cfg.minari_root:
        os.environ["MINARI_DATASETS_PATH"] = str(cfg.minari_root)
    dataset = minari.load_dataset(cfg.dataset_id)
    task = _infer_task(dataset, cfg.task)
    if task not in ADROIT_TASKS:
        raise SystemExit(f"unknown Adroit task {task!r}; valid: {', '.join(ADROIT_TASKS)}")
    root = Path(cfg.root)
    if root.exists() and any(root.iterdir()):
        raise SystemExit(f"{root} exists and is not empty; choose a new --root")
    if "pointcloud" in cfg.obs_types:
        env_obs = "pointcloud"
    else:
        env_obs = "pixels_agent_pos" if "pixels" in cfg.obs_types else "state"
    if "pointcloud" in cfg.obs_types and "pixels" in cfg.obs_types:
        raise SystemExit("import pointcloud and pixels into separate datasets (one env obs type per replay)")
    env_cfg = FocalAdroitEnvConfig(task=task, obs_type=env_obs, terminate_on_success=False, episode_length=10**6)
    action_dim = ADROIT_TASKS[task][1]
    image_hw = (env_cfg.observation_height, env_cfg.observation_width)
    features = _features(cfg.obs_types, action_dim, env_cfg.num_points, image_hw)
    out = LeRobotDataset.create(
        repo_id=cfg.repo_id, fps=env_cfg.fps, features=features, root=root, use_videos=False, robot_type="adroit_hand",
    )
    env = env_cfg.make_single_env(task)
    episodes = list(dataset.storage.get_episode_metadata(dataset.episode_indices))
    if cfg.max_episodes is not None:
        episodes = episodes[: cfg.max_episodes]
    summary = {"task": task, "episodes_in": len(episodes), "written": 0, "failed": 0, "diverged": 0, "no_seed": 0}
    try:
        for meta in tqdm(episodes, unit="episode", desc=f"import {cfg.dataset_id}"):
            if meta.get("seed") is None:
                summary["no_seed"] += 1
                logging.warning("episode %s has no reset seed; cannot replay it", meta["id"])
                continue
            ep = dataset[int(meta["id"])]
            actions = np.asarray(ep.actions)
            if actions.ndim != 2 or actions.shape[1] != action_dim:
                raise SystemExit(
                    f"episode {meta['id']} actions have shape {actions.shape}; {task} needs (T, {action_dim})"
                )
            stored = np.asarray(ep.observations) if isinstance(ep.observations, np.ndarray) else None
            frames, success, drift = replay_episode(env, int(meta["seed"]), actions, stored, "pixels" in cfg.obs_types)
            if drift > cfg.max_drift:
                summary["diverged"] += 1
                logging.warning("episode %s: replay drifts %.3g from the stored observations; skipped",
                                meta["id"], drift)
                continue
            if cfg.only_successful and not success:
                summary["failed"] += 1
                continue
            for frame in frames:
                out.add_frame({**frame, "task": TASK_DESCRIPTIONS[task]})
            out.save_episode()
            summary["written"] += 1
    finally:
        env.close()
        out.finalize()
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "lerobot-focal-import-minari")
    parser.add_argument("--dataset_id", required=True, help="Minari dataset id, e.g. adroit/door/expert-v0")
    parser.add_argument("--root", required=True, type=Path, help="new LeRobotDataset directory")
    parser.add_argument("--task", default=None, help="hammer|door|pen (default: from the Minari env spec)")
    parser.add_argument("--repo_id", default="local/focal_adroit")
    parser.add_argument("--obs_types", default="pointcloud", help="state, pointcloud or pixels (comma-separated)")
    parser.add_argument("--all_episodes", action="store_true", help="keep episodes whose replay does not succeed")
    parser.add_argument("--max_drift", type=float, default=1e-3)
    parser.add_argument("--max_episodes", type=int, default=None)
    parser.add_argument("--minari_root", default=None, help="Minari datasets directory (default: MINARI_DATASETS_PATH)")
    args = parser.parse_args(argv)
    obs_types = tuple(o.strip() for o in args.obs_types.split(",") if o.strip())
    if not obs_types or any(o not in ("state", "pointcloud", "pixels") for o in obs_types):
        parser.error("--obs_types must be a comma-separated subset of state, pointcloud, pixels")
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    summary = import_minari(
        ImportConfig(
            dataset_id=args.dataset_id, root=args.root, task=args.task, repo_id=args.repo_id, obs_types=obs_types,
            only_successful=not args.all_episodes, max_drift=args.max_drift, max_episodes=args.max_episodes,
            minari_root=args.minari_root,
        )
    )
    print(
        f"{summary['task']}: {summary['written']} of {summary['episodes_in']} episodes written "
        f"({summary['failed']} unsuccessful, {summary['diverged']} diverged, {summary['no_seed']} without seed) "
        f"-> {args.root}",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
