"""What makes a CPU training step of `focal` cheaper without changing what it computes.

    lerobot-focal-bench train-step [--down-dims 32 64 128] [--batch 64] [--repeats 30] [--out docs/benchmarks]

One process, every variant built from the same weights and timed round-robin (``policy_speed.time_ms``), so a
shared machine's load hits all alike and the ratios hold. A step is what `lerobot-train` does per batch:
forward (with the EMA consistency target), backward, gradient clipping, optimizer step, EMA update. Variants:

- ``adamw``: LeRobot's AdamW (for-loop update), the optimizer before ``focal_adamw``;
- ``focal_adamw``: the plugin's default, PyTorch's fused AdamW (same arithmetic, one kernel);
- ``focal_adamw, 2 threads``: the same with two intra-op threads instead of one;
- ``focal_adamw, batch 2×``: twice the batch, reported per sample (what trading steps for batch size buys);
- ``focal_adamw + torch.compile`` (``--compile``): the velocity U-Net compiled; its one-off compile time is
  reported beside it.

Writes ``train_step_cpu.json`` and ``train_step_cpu.md`` (a table with ms per step, ms per sample and the ratio
to ``adamw``).
"""

from __future__ import annotations

import copy
import json
import platform
import time
from pathlib import Path

import torch

from lerobot_focal.benchmarks.policy_speed import ACTION_DIM, ENV_DIM, STATE_DIM, build_focal, time_ms
from lerobot_focal.console import doc_parser


def _batch(b: int, horizon: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    return {
        "observation.state": torch.randn(b, 2, STATE_DIM, generator=g),
        "observation.environment_state": torch.randn(b, 2, ENV_DIM, generator=g),
        "action": torch.randn(b, horizon, ACTION_DIM, generator=g),
    }


def _step_fn(policy, optimizer, batch, threads: int):
    def step() -> None:
        torch.set_num_threads(threads)
        loss, _ = policy.forward(batch)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.get_optim_params(), 10.0)
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        policy.update()
        torch.set_num_threads(1)

    return step


def run(down_dims: tuple[int, ...], batch: int, repeats: int, compile_: bool, out: Path) -> list[dict]:
    from lerobot.optim import AdamWConfig

    torch.manual_seed(0)
    torch.set_num_threads(1)
    base = build_focal(down_dims, "cpu")
    base.train()
    cfg = base.config
    preset = cfg.get_optimizer_preset()

    def variant(opt_cfg, b: int, threads: int = 1, compiled: bool = False):
        policy = copy.deepcopy(base)
        if compiled:
            policy.model.velocity_net = torch.compile(policy.model.velocity_net)
            policy.ema_model.velocity_net = torch.compile(policy.ema_model.velocity_net)
        return _step_fn(policy, opt_cfg.build(policy.get_optim_params()), _batch(b, cfg.horizon), threads), b

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
    medians = time_ms({k: v[0] for k, v in variants.items()}, "cpu", repeats, warmup=3)
    ref = medians["adamw"] / batch
    rows = []
    for name, (_, b) in variants.items():
        per_sample = medians[name] / b
        rows.append({"variant": name, "batch": b, "ms_per_step": round(medians[name], 2),
                     "ms_per_sample": round(per_sample, 4), "speedup_per_sample": round(ref / per_sample, 3)})
    result = {"down_dims": list(down_dims), "batch": batch, "repeats": repeats, "threads_default": 1,
              "compile_s": compile_s, "machine": platform.processor() or platform.machine(), "rows": rows}
    out.mkdir(parents=True, exist_ok=True)
    (out / "train_step_cpu.json").write_text(json.dumps(result, indent=1))
    md = [f"# focal training step on the CPU: U-Net {'/'.join(map(str, down_dims))}, batch {batch}", "",
          "Median of the round-robin repeats in one process (`lerobot-focal-bench train-step`); step = forward with "
          "the EMA target, backward, clip, optimizer step, EMA update. Speed-up is per training sample, against "
          "LeRobot's AdamW.", "", "| variant | batch | ms / step | ms / sample | speed-up per sample |",
          "|---|---|---|---|---|"]
    md += [f"| {r['variant']} | {r['batch']} | {r['ms_per_step']:.1f} | {r['ms_per_sample']:.3f} | "
           f"{r['speedup_per_sample']:.2f}× |" for r in rows]
    if compile_s is not None:
        md += ["", f"torch.compile's first step (compilation) took {compile_s:.0f} s."]
    (out / "train_step_cpu.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench train-step")
    p.add_argument("--down-dims", type=int, nargs="+", default=[32, 64, 128])
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--repeats", type=int, default=30)
    p.add_argument("--compile", action="store_true", help="also time torch.compile (compiles for ~1 min on a CPU)")
    p.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    args = p.parse_args(argv)
    run(tuple(args.down_dims), args.batch, args.repeats, args.compile, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
