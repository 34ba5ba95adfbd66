"""FocalPolicy learns: after a short training run its one-step predictions track held-out trajectories.

Real pieces throughout: a LeRobotDataset on disk, LeRobot's delta-timestamp windowing and padding, the
policy's own processors, one network evaluation per prediction. The dataset items are read once and kept in
memory (the stock reader costs ~tens of ms per point-cloud item), then re-batched for 400 steps.
"""

import numpy as np
import torch
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.constants import ACTION

from lerobot_focal.datasets.synthetic import SyntheticSpec, episode_arrays, write_synthetic_dataset
from lerobot_focal.policy import FocalConfig, FocalPolicy, make_focal_pre_post_processors
from lerobot.utils.feature_utils import dataset_to_policy_features


def _heldout_windows(spec: SyntheticSpec, cfg: FocalConfig):
    """Observation windows and true macro-trajectories from episodes the policy never saw (another seed)."""
    held = SyntheticSpec(**{**spec.__dict__, "seed": 123, "num_episodes": 4})
    obs, targets = [], []
    for ep in range(held.num_episodes):
        arr = episode_arrays(held, ep)
        for t in range(1, held.episode_length - cfg.horizon, 5):
            obs.append({k: torch.from_numpy(arr[k][t - 1 : t + 1]) for k in ("observation.state", "observation.pointcloud") if k in arr})
            targets.append(arr[ACTION][t : t + cfg.horizon])
    batch = {k: torch.stack([o[k] for o in obs]) for k in obs[0]}
    return batch, torch.from_numpy(np.stack(targets))


def _proximal_rmse(policy, pre, post, obs, targets, cfg) -> float:
    policy.eval()
    torch.manual_seed(0)
    with torch.no_grad():
        normed = pre(dict(obs))
        pred = policy.sample_macro_trajectory({k: normed[k] for k in obs})
        pred = post(pred)
    err = pred[:, : cfg.chunk_size] - targets[:, : cfg.chunk_size]
    return err.pow(2).mean().sqrt().item()


def test_short_training_run_predicts_heldout_trajectories(tmp_path):
    torch.manual_seed(0)
    spec = SyntheticSpec(num_episodes=12, num_points=64)
    write_synthetic_dataset(tmp_path / "ds", spec)
    cfg = FocalConfig(device="cpu", down_dims=(32, 64, 128), optimizer_lr=1e-3, scheduler_warmup_steps=20)
    meta = LeRobotDataset(repo_id="local/focal_synthetic", root=tmp_path / "ds").meta
    feats = dataset_to_policy_features(meta.features)
    cfg.output_features = {k: f for k, f in feats.items() if k == ACTION}
    cfg.input_features = {k: f for k, f in feats.items() if k != ACTION}
    ds = LeRobotDataset("local/focal_synthetic", root=tmp_path / "ds", delta_timestamps=resolve_delta_timestamps(cfg, meta))
    items = [ds[i] for i in range(len(ds))]
    pre, post = make_focal_pre_post_processors(cfg, dataset_stats=meta.stats)
    policy = FocalPolicy(cfg)
    obs, targets = _heldout_windows(spec, cfg)
    untrained = _proximal_rmse(policy, pre, post, obs, targets, cfg)

    policy.train()
    opt = torch.optim.AdamW(policy.get_optim_params(), lr=cfg.optimizer_lr, betas=cfg.optimizer_betas)
    keys = ["observation.state", "observation.pointcloud", ACTION]
    for _ in range(400):
        idx = torch.randint(len(items), (64,))
        batch = pre({k: torch.stack([items[i][k] for i in idx]) for k in keys})
        loss, _ = policy.forward(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        policy.update()
    trained = _proximal_rmse(policy, pre, post, obs, targets, cfg)
    action_scale = targets.std().item()
    print(f"proximal RMSE untrained={untrained:.4f} trained={trained:.4f} action std={action_scale:.3f}")
    assert trained < 0.2 * untrained
    assert trained < 0.15 * action_scale
