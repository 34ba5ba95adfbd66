"""Checkpoint metrics of one grid run: open-loop compounding error, TS score, latency per chunk, NFE.

Latency per chunk and NFE are measured the same way for every policy type (focal, diffusion and its variants,
ACT): a timed ``select_action`` right after ``reset()`` at batch 1, and forward hooks on the network a chunk
calls (`UNET_CLASS_NAMES`).

Run as its own process by the grid (``python -m lerobot_focal.benchmarks.grid.analyze CKPT HELDOUT_ROOT
HELDOUT_REPO OUT.json``) so each run's torch threads and memory end with it. The checkpoint is loaded as
`lerobot-eval` loads one: ``get_policy_class(type).from_pretrained`` plus the saved processors, so every
policy type of the grid is measured by the same code.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from .metrics import compounding_error, mean_curve, ts_score

#: The networks whose calls are counted as NFE: the denoising U-Net (focal, diffusion and its variants) and ACT's
#: whole encoder-decoder transformer (`lerobot.policies.act.modeling_act.ACT`, one call per chunk).
UNET_CLASS_NAMES = ("DiffusionConditionalUnet1d", "ACT")


def load_policy(checkpoint: Path, device: str = "cpu"):
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    cfg = PreTrainedConfig.from_pretrained(checkpoint)
    cfg.device = device
    policy = get_policy_class(cfg.type).from_pretrained(checkpoint, config=cfg)
    policy.eval()
    pre, post = make_pre_post_processors(
        cfg, pretrained_path=str(checkpoint), preprocessor_overrides={"device_processor": {"device": device}}
    )
    return policy, pre, post


def _count_unet_calls(policy) -> list[int]:
    """Forward hooks on every counted network of the policy (focal and diffusion_ema keep an EMA copy) -> a call
    counter."""
    counter = [0]
    for module in policy.modules():
        if type(module).__name__ in UNET_CLASS_NAMES:
            module.register_forward_hook(lambda *_: counter.__setitem__(0, counter[0] + 1))
    return counter


def heldout_episodes(root: Path, repo_id: str, keys: list[str]) -> list[dict[str, np.ndarray]]:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset(repo_id, root=root)
    hf = ds.hf_dataset.with_format("numpy")
    images = {k for k in keys if ds.meta.features[k]["dtype"] in ("image", "video")}
    if videos := [k for k in images if ds.meta.features[k]["dtype"] == "video"]:
        raise ValueError(f"{root}: {videos} are stored as video; the analysis reads frames stored as images")
    episodes = []
    for ep in range(ds.meta.total_episodes):
        rows = hf.filter(lambda e, ep=ep: e == ep, input_columns="episode_index")
        episode = {k: np.stack(rows[k]).astype(np.float32) for k in [*keys, "action"]}
        for k in images:  # stored (H, W, C) uint8; policies take (C, H, W) in [0, 1], as LeRobotDataset gives it
            episode[k] = np.ascontiguousarray(episode[k].transpose(0, 3, 1, 2)) / 255.0
        episodes.append(episode)
    return episodes


def analyze(checkpoint: Path, heldout_root: Path, heldout_repo: str, device: str = "cpu",
            latency_repeats: int = 30) -> dict:
    policy, pre, post = load_policy(checkpoint, device)
    keys = [k for k in policy.config.input_features]
    episodes = heldout_episodes(heldout_root, heldout_repo, keys)
    calls = _count_unet_calls(policy)

    # Open loop along each held-out episode: recorded observations in, executed actions out.
    predicted, expert, curves = [], [], []
    chunks = 0
    for ep in episodes:
        policy.reset()
        actions = []
        for t in range(len(ep["action"])):
            obs = {k: torch.from_numpy(ep[k][t])[None] for k in keys}
            with torch.no_grad():
                actions.append(post(policy.select_action(pre(obs))).cpu().numpy()[0])
        chunks += -(-len(ep["action"]) // policy.config.n_action_steps)
        predicted.append(np.stack(actions))
        expert.append(ep["action"])
        curves.append(compounding_error(ep["action"], predicted[-1]))
    nfe = calls[0] / max(chunks, 1)

    # Latency of one chunk (batch 1): a select_action right after reset() always computes a new chunk. This is
    # the deployed path of every policy type (diffusion's predict_action_chunk reads the queues select_action
    # fills). Median of the repeats after warm-up.
    obs = pre({k: torch.from_numpy(episodes[0][k][0])[None] for k in keys})
    timings = []
    with torch.no_grad():
        for i in range(latency_repeats + 3):
            policy.reset()
            if device.startswith("cuda"):
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            policy.select_action(dict(obs))
            if device.startswith("cuda"):
                torch.cuda.synchronize()
            if i >= 3:
                timings.append(time.perf_counter() - t0)
    curve = mean_curve(curves)
    return {
        "compounding_error": float(curve.mean()),
        "compounding_curve": [round(float(x), 6) for x in curve],
        "ts_score": ts_score(expert, predicted),
        "heldout_action_rmse": float(
            np.sqrt(np.mean([((p - e) ** 2).mean() for p, e in zip(predicted, expert, strict=True)]))
        ),
        "nfe": nfe,
        "latency_ms": 1000 * statistics.median(timings),
        "n_params": sum(p.numel() for p in policy.parameters() if p.requires_grad),
        "heldout_episodes": len(episodes),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("heldout_root", type=Path)
    parser.add_argument("heldout_repo")
    parser.add_argument("out", type=Path)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    import lerobot_focal  # noqa: F401  (registers focal and diffusion_fco)

    result = analyze(args.checkpoint, args.heldout_root, args.heldout_repo, args.device)
    args.out.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
