"""Quick demo: write a local LeRobotDataset, train `focal` with `lerobot-train`, check its one-step predictions.

This is the README's main job until the MetaWorld pipeline replaces it. Everything is real: the dataset is a
LeRobotDataset on disk, training is LeRobot's own `lerobot-train` process (its progress log is shown), and the
check loads the saved checkpoint the way `lerobot-eval` does (`from_pretrained` + saved processors), then rolls
the policy along held-out episodes, one network evaluation per chunk of H actions.

    python -m lerobot_focal.demos.synthetic_reach --steps 1000 --output outputs/demo
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import torch

from lerobot_focal.console import console_script, doc_parser
from lerobot_focal.constants import OBS_POINTCLOUD
from lerobot_focal.datasets.making.synthetic import SyntheticSpec, episode_arrays, write_synthetic_dataset
from lerobot_focal.figures import save_png
from lerobot_focal.presets import preset_path

CPU_PRESET = preset_path("cpu")


def train(dataset_root: Path, out_dir: Path, steps: int, batch_size: int) -> Path:
    """Run `lerobot-train` in a subprocess and return the last checkpoint's `pretrained_model` folder."""
    exe = console_script("lerobot-train")
    cmd = [
        str(exe) if exe.exists() else "lerobot-train",
        f"--config_path={CPU_PRESET}",
        "--dataset.repo_id=local/focal_synthetic",
        f"--dataset.root={dataset_root}",
        f"--output_dir={out_dir}",
        f"--steps={steps}",
        f"--batch_size={batch_size}",
        f"--save_freq={steps}",
        f"--log_freq={max(steps // 15, 1)}",
    ]
    # The plugin's in-memory reader (docs/data_throughput.md): same items as LeRobot's, ~40x cheaper to read.
    env = {**os.environ, "LEROBOT_FOCAL_FAST_READER": "1"}
    print("[demo] $ LEROBOT_FOCAL_FAST_READER=1", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, env=env)
    return out_dir / "checkpoints" / "last" / "pretrained_model"


def rollout_errors(checkpoint: Path, spec: SyntheticSpec, episodes: int = 4) -> tuple[list[float], list[np.ndarray]]:
    """Per held-out episode: RMSE of the actions `select_action` returns vs the demonstrated ones (open loop)."""
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_focal.policy import FocalPolicy

    policy = FocalPolicy.from_pretrained(checkpoint)
    policy.eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    held = SyntheticSpec(**{**spec.__dict__, "seed": spec.seed + 1000, "num_episodes": episodes})
    rmses, predicted = [], []
    for ep in range(episodes):
        arr = episode_arrays(held, ep)
        policy.reset()
        actions = []
        for t in range(held.episode_length):
            obs = {k: torch.from_numpy(arr[k][t])[None] for k in ("observation.state", OBS_POINTCLOUD)}
            with torch.no_grad():
                actions.append(post(policy.select_action(pre(obs)))[0].numpy())
        actions = np.stack(actions)
        predicted.append(actions)
        rmses.append(float(np.sqrt(((actions - arr["action"]) ** 2).mean())))
    return rmses, predicted


def plot(spec: SyntheticSpec, predicted: list[np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    held = SyntheticSpec(**{**spec.__dict__, "seed": spec.seed + 1000, "num_episodes": len(predicted)})
    fig, ax = plt.subplots(figsize=(5, 5))
    for ep, pred in enumerate(predicted):
        true = episode_arrays(held, ep)["action"]
        color = f"C{ep}"
        ax.plot(true[:, 0], true[:, 1], color=color, lw=3, alpha=0.35, label="demonstration" if ep == 0 else None)
        ax.plot(pred[:, 0], pred[:, 1], color=color, lw=1.2, marker=".",
                label="focal (1 NFE / chunk)" if ep == 0 else None)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title("Held-out episodes: focal vs demonstration")
    ax.legend(loc="best")
    ax.set_aspect("equal")
    save_png(fig, path, dpi=120)


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "python -m lerobot_focal.demos.synthetic_reach")
    parser.add_argument("--output", type=Path, default=Path("outputs/demo"))
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--episodes", type=int, default=12)
    args = parser.parse_args(argv)

    spec = SyntheticSpec(num_episodes=args.episodes, num_points=128)
    dataset_root = args.output / "dataset"
    train_dir = args.output / "train"
    if train_dir.exists():
        shutil.rmtree(train_dir)  # lerobot-train refuses an existing output_dir unless resuming
    if not (dataset_root / "meta" / "info.json").exists():
        shutil.rmtree(dataset_root, ignore_errors=True)
        print(f"[demo] writing {spec.num_episodes} episodes to {dataset_root}", flush=True)
        write_synthetic_dataset(dataset_root, spec)
    t0 = time.perf_counter()
    checkpoint = train(dataset_root, train_dir, args.steps, args.batch_size)
    train_s = time.perf_counter() - t0
    rmses, predicted = rollout_errors(checkpoint, spec)
    plot(spec, predicted, args.output / "heldout_rollouts.png")
    action_std = float(np.concatenate([episode_arrays(spec, e)["action"] for e in range(4)]).std())
    result = {
        "steps": args.steps,
        "train_seconds": round(train_s, 1),
        "heldout_action_rmse_per_episode": [round(r, 4) for r in rmses],
        "heldout_action_rmse_median": round(float(np.median(rmses)), 4),
        "action_std": round(action_std, 4),
        "checkpoint": str(checkpoint),
    }
    (args.output / "result.json").write_text(json.dumps(result, indent=2))
    print(f"\n[demo] trained {args.steps} steps in {train_s:.0f} s; checkpoint: {checkpoint}")
    print(f"[demo] held-out action RMSE (median of 4 episodes): {result['heldout_action_rmse_median']:.4f} "
          f"(action std {action_std:.3f})")
    print(f"[demo] plot: {args.output / 'heldout_rollouts.png'}   results: {args.output / 'result.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
