"""What makes a CPU training step of `focal` cheaper without changing what it computes.

    lerobot-focal-bench train-step [--inputs state|pointcloud] [--down-dims 32 64 128] [--batch 64]
                                   [--repeats 30] [--out docs/benchmarks]

One process, every variant built from the same weights and timed round-robin (``policy_speed.time_ms``), so a
shared machine's load hits all alike and the ratios hold. A step is what `lerobot-train` does per batch:
forward (with the EMA consistency target), backward, gradient clipping, optimizer step, EMA update.

``--inputs state`` (the grid's low-dim focal: 9-d state + 39-d object poses) times:

- ``adamw``: LeRobot's AdamW (for-loop update), the optimizer before ``focal_adamw``;
- ``focal_adamw``: the plugin's default, PyTorch's fused AdamW (same arithmetic, one kernel);
- ``focal_adamw, 2 threads``: the same with two intra-op threads instead of one;
- ``focal_adamw, batch 2×``: twice the batch, reported per sample (what trading steps for batch size buys);
- ``focal_adamw + torch.compile`` (``--compile``): the velocity U-Net compiled; its one-off compile time is
  reported beside it.

``--inputs pointcloud`` (the grid's focal on 512-point clouds + 9-d state) times the point-cloud encoder's
backward over every point (``dense max-pool backward``) against the default, which runs it on the points that
win the max-pool only (`PointCloudEncoder`); it also trains both from the same weights on the same noise for
``--agreement-steps`` steps and reports how far their losses drift apart (float rounding only, if the two
compute the same thing).

Writes ``train_step_cpu[_pointcloud].json`` and ``.md`` (a table with ms per step, ms per sample and the ratio
to the first variant).
"""

from __future__ import annotations

import contextlib
import copy
import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import torch

from lerobot_focal.benchmarks.policy_speed import (
    ACTION_DIM,
    ENV_DIM,
    STATE_DIM,
    benchmark_features,
    build_focal,
    time_ms,
)
from lerobot_focal.console import doc_parser
from lerobot_focal.constants import OBS_POINTCLOUD


def dataset_clouds(root: Path, batch: int) -> torch.Tensor:
    """(batch, 2, P, 3): pairs of consecutive point clouds spread over a LeRobotDataset's frames, min-max scaled
    per xyz channel to [-1, 1] as the policy's normaliser does with the dataset's statistics."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    frames = LeRobotDataset("local/clouds", root=root).hf_dataset.with_format("torch")
    starts = torch.linspace(0, len(frames) - 2, batch).long().tolist()
    pairs = torch.stack([frames[i: i + 2][OBS_POINTCLOUD][..., :3] for i in starts])
    lo, hi = pairs.amin(dim=(0, 1, 2)), pairs.amax(dim=(0, 1, 2))
    return (pairs - lo) / (hi - lo).clamp_min(1e-8) * 2 - 1


def policy_and_batch(inputs: str, batch: int, down_dims: tuple[int, ...] = (32, 64, 128),
                     clouds: torch.Tensor | None = None):
    """The grid's focal (U-Net `down_dims`, training mode) on `inputs`, and one fixed batch for it (point clouds:
    `clouds`, (batch, 2, P, 3), or Gaussian noise)."""
    from lerobot.configs.types import FeatureType, PolicyFeature

    g = torch.Generator().manual_seed(1)
    features = benchmark_features()[0]
    if inputs == "pointcloud":
        if clouds is None:
            clouds = torch.randn(batch, 2, 512, 3, generator=g)
        features = {"observation.state": features["observation.state"],
                    OBS_POINTCLOUD: PolicyFeature(type=FeatureType.STATE, shape=tuple(clouds.shape[2:]))}
        extra = {OBS_POINTCLOUD: clouds}
    else:
        extra = {"observation.environment_state": torch.randn(batch, 2, ENV_DIM, generator=g)}
    torch.manual_seed(0)
    policy = build_focal(down_dims, "cpu", features).train()
    data = {"observation.state": torch.randn(batch, 2, STATE_DIM, generator=g), **extra,
            "action": torch.randn(batch, policy.config.horizon, ACTION_DIM, generator=g),
            "action_is_pad": torch.zeros(batch, policy.config.horizon, dtype=torch.bool)}
    return policy, data


def training_step(policy, optimizer, batch, threads: int = 1, autocast: bool = False) -> Callable[[], float]:
    """One optimizer step of `policy` on `batch` as lerobot-train takes it (clip at 10, zero grads, EMA update),
    as a callable the benchmarks time; torch runs it on `threads` threads and goes back to one. `autocast`: the
    forward under bf16 autocast, as LeRobot's use_amp runs it on a CPU."""

    def step() -> float:
        torch.set_num_threads(threads)
        with torch.autocast("cpu", dtype=torch.bfloat16) if autocast else contextlib.nullcontext():
            loss, _ = policy.forward(batch)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.get_optim_params(), 10.0)
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        policy.update()
        torch.set_num_threads(1)
        return float(loss.detach())

    return step


def _with_dense_cloud_backward(policy):
    # The online encoder only: the EMA target runs without gradients, where both paths are the same.
    policy.model.obs_encoder.pointcloud.winners_only_backward = False
    return policy


def _state_variants(base, data: dict[str, torch.Tensor], batch: int, compile_: bool) -> tuple[dict, float | None]:
    """The optimizer, thread, batch and compile variants; `data` holds 2 × `batch` samples."""
    from lerobot.optim import AdamWConfig

    preset = base.config.get_optimizer_preset()

    def variant(opt_cfg, b: int, threads: int = 1, compiled: bool = False):
        policy = copy.deepcopy(base)
        if compiled:
            policy.model.velocity_net = torch.compile(policy.model.velocity_net)
            policy.ema_model.velocity_net = torch.compile(policy.ema_model.velocity_net)
        step = training_step(policy, opt_cfg.build(policy.get_optim_params()), {k: v[:b] for k, v in data.items()},
                        threads)
        return step, b

    plain = AdamWConfig(lr=preset.lr, betas=preset.betas, eps=preset.eps, weight_decay=preset.weight_decay)
    variants = {
        "adamw": variant(plain, batch),
        "focal_adamw": variant(preset, batch),
        "focal_adamw, 2 threads": variant(preset, batch, threads=2),
        f"focal_adamw, batch {2 * batch}": variant(preset, 2 * batch),
    }
    compile_s = None
    if compile_:
        fn, b = variant(preset, batch, compiled=True)
        t0 = time.perf_counter()
        fn()
        compile_s = time.perf_counter() - t0
        variants["focal_adamw + torch.compile"] = (fn, b)
    return variants, compile_s


def _pointcloud_variants(base, data, agreement_steps: int) -> tuple[dict, dict]:
    """Dense vs winners-only point-cloud backward: timed variants, and the loss drift between them."""
    preset = base.config.get_optimizer_preset()
    builds = {"focal_adamw, dense max-pool backward": lambda: _with_dense_cloud_backward(copy.deepcopy(base)),
              "focal_adamw, winners-only backward (default)": lambda: copy.deepcopy(base)}
    losses = {}
    for name, build in builds.items():
        policy = build()
        step = training_step(policy, preset.build(policy.get_optim_params()), data, 1)
        curve = []
        for i in range(agreement_steps):
            torch.manual_seed(100 + i)  # the same noise and flow times for both
            curve.append(step())
        losses[name] = curve
    dense, winners = losses.values()
    drift = max(abs(a - b) / abs(a) for a, b in zip(dense, winners, strict=True)) if agreement_steps else None
    # How many points of each cloud hold some channel's maximum at the start.
    counts = base.model.obs_encoder.pointcloud.max_winners(data[OBS_POINTCLOUD].flatten(0, 1)).sum(-1).tolist()
    agreement = {"steps": agreement_steps, "loss_dense": dense, "loss_winners": winners,
                 "max_relative_loss_difference": drift,
                 "winners_per_cloud": {"mean": sum(counts) / len(counts), "max": max(counts),
                                       "points": data[OBS_POINTCLOUD].shape[-2]}}
    variants = {}
    for name, build in builds.items():
        policy = build()
        variants[name] = (training_step(policy, preset.build(policy.get_optim_params()), data, 1), len(data["action"]))
    return variants, agreement


def run(down_dims: tuple[int, ...], batch: int, repeats: int, compile_: bool, out: Path, inputs: str = "state",
        agreement_steps: int = 20, clouds_root: Path | None = None) -> list[dict]:
    torch.manual_seed(0)
    torch.set_num_threads(1)
    compile_s = agreement = None
    if inputs == "pointcloud":
        clouds = dataset_clouds(clouds_root, batch) if clouds_root else None
        base, data = policy_and_batch(inputs, batch, down_dims, clouds)
        variants, agreement = _pointcloud_variants(base, data, agreement_steps)
    else:
        base, data = policy_and_batch(inputs, 2 * batch, down_dims)
        variants, compile_s = _state_variants(base, data, batch, compile_)
    medians = time_ms({k: v[0] for k, v in variants.items()}, "cpu", repeats, warmup=3)
    first = next(iter(variants))
    ref = medians[first] / variants[first][1]
    rows = []
    for name, (_, b) in variants.items():
        per_sample = medians[name] / b
        rows.append({"variant": name, "batch": b, "ms_per_step": round(medians[name], 2),
                     "ms_per_sample": round(per_sample, 4), "speedup_per_sample": round(ref / per_sample, 3)})
    # Point-cloud steps depend on glibc's malloc settings (`lerobot-focal-bench allocator`): say which ran.
    malloc = " ".join(f"{k}={v}" for k, v in sorted(os.environ.items()) if k.startswith("MALLOC_")) or None
    result = {"inputs": inputs, "clouds": str(clouds_root) if clouds_root else None,
              "down_dims": list(down_dims), "batch": batch, "repeats": repeats,
              "threads_default": 1, "malloc_env": malloc, "compile_s": compile_s, "agreement": agreement,
              "machine": platform.processor() or platform.machine(), "rows": rows}
    stem = "train_step_cpu" + ("_pointcloud" if inputs == "pointcloud" else "")
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.json").write_text(json.dumps(result, indent=1))
    what = "512-point clouds + 9-d state" if inputs == "pointcloud" else "9-d state + 39-d object poses"
    command = f"lerobot-focal-bench train-step --inputs {inputs}" + (f" --clouds {clouds_root}" if clouds_root else "")
    md = [f"# focal training step on the CPU: {what}, U-Net {'/'.join(map(str, down_dims))}, batch {batch}", "",
          f"Median of {repeats} round-robin repeats in one process (`{command}`); step = forward with the EMA "
          f"target, backward, clip, optimizer step, EMA update. Speed-up is per training sample, against {first}. "
          f"glibc malloc: {f'`{malloc}`' if malloc else 'defaults'}.", "",
          "| variant | batch | ms / step | ms / sample | speed-up per sample |", "|---|---|---|---|---|"]
    md += [f"| {r['variant']} | {r['batch']} | {r['ms_per_step']:.1f} | {r['ms_per_sample']:.3f} | "
           f"{r['speedup_per_sample']:.2f}× |" for r in rows]
    if compile_s is not None:
        md += ["", f"torch.compile's first step (compilation) took {compile_s:.0f} s."]
    if agreement:
        w = agreement["winners_per_cloud"]
        source = f"the clouds of `{clouds_root}`" if clouds_root else "Gaussian noise as clouds"
        md += ["", f"Points that hold some channel's maximum, per cloud of the batch ({source}, initial weights): "
                   f"{w['mean']:.1f} on average, {w['max']} at most, of {w['points']}."]
    if agreement and agreement["steps"]:
        md += ["", f"Trained side by side from the same weights on the same noise for {agreement['steps']} steps, "
                   f"the two losses differ by at most {agreement['max_relative_loss_difference']:.1e} of the loss "
                   f"(first {agreement['loss_dense'][0]:.4f} / {agreement['loss_winners'][0]:.4f}, last "
                   f"{agreement['loss_dense'][-1]:.4f} / {agreement['loss_winners'][-1]:.4f})."]
    (out / f"{stem}.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench train-step")
    p.add_argument("--inputs", choices=["state", "pointcloud"], default="state")
    p.add_argument("--down-dims", type=int, nargs="+", default=[32, 64, 128])
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--repeats", type=int, default=30)
    p.add_argument("--compile", action="store_true", help="also time torch.compile (compiles for ~1 min on a CPU)")
    p.add_argument("--agreement-steps", type=int, default=20,
                   help="with --inputs pointcloud: steps trained side by side to compare the two losses")
    p.add_argument("--clouds", type=Path, default=None, metavar="DATASET_ROOT",
                   help="with --inputs pointcloud: take the batch's clouds from this LeRobotDataset (e.g. a grid "
                        "dataset); Gaussian noise otherwise, whose clouds have more max-pool winners than a scene's")
    p.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    args = p.parse_args(argv)
    if args.compile and args.inputs != "state":
        p.error("--compile times the state inputs' U-Net: run it with --inputs state")
    if args.clouds is not None and not (args.clouds / "meta" / "info.json").is_file():
        p.error(f"--clouds {args.clouds}: no LeRobotDataset there (meta/info.json is missing)")
    run(tuple(args.down_dims), args.batch, args.repeats, args.compile, args.out, args.inputs, args.agreement_steps,
        args.clouds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
