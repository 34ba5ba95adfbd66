"""glibc's malloc settings against a CPU training step of focal: the grid's ``MALLOC_ENV`` or the defaults.

    lerobot-focal-bench allocator [--inputs pointcloud state] [--rounds 3] [--steps 8] [--out docs/benchmarks]

Why: a point-cloud step allocates activations of up to 64 MB, at or above glibc's largest mmap threshold
(32 MB), so by default each one is mapped, page-faulted in zero-filled and unmapped at every step.

Allocator settings are fixed when a process starts, so each setting runs in its own child process, the two
alternated for ``--rounds`` rounds (load from other processes hits both alike). Each child times ``--steps``
steps, after two warm-up steps, of the grid's focal (U-Net 32/64/128, batch 64, one thread: forward with the EMA
target, backward, clip, fused AdamW, EMA update) from fixed weights and data, and reports its final loss and a
checksum of its weights, which must match bit for bit between the settings. Writes ``allocator_cpu.json`` and
``allocator_cpu.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from lerobot_focal.console import doc_parser

SETTINGS = ("glibc defaults", "MALLOC_ENV (grid)")


def child(inputs: str, steps: int, batch: int) -> dict:
    """Time ``steps`` training steps in this process (whatever its malloc settings) and fingerprint the result."""
    import torch

    from lerobot_focal.benchmarks.train_step import policy_and_batch, training_step

    torch.set_num_threads(1)
    policy, data = policy_and_batch(inputs, batch)
    step = training_step(policy, policy.config.get_optimizer_preset().build(policy.get_optim_params()), data, 1)
    torch.manual_seed(2)
    for _ in range(2):
        step()
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    torch.manual_seed(3)
    loss, _ = policy.forward(data)
    checksum = sum(float(p.double().sum()) for p in policy.parameters())
    return {"s_per_step": statistics.median(times), "loss": float(loss), "checksum": checksum}


def _env(setting: str) -> dict[str, str]:
    from lerobot_focal.benchmarks.grid.run import MALLOC_ENV

    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env["OMP_NUM_THREADS"] = "1"
    return {**env, **MALLOC_ENV} if setting == SETTINGS[1] else env


def run(inputs: list[str], rounds: int, steps: int, batch: int, out: Path) -> dict:
    result: dict = {"rounds": rounds, "steps": steps, "batch": batch, "inputs": {}}
    for inp in inputs:
        samples: dict[str, list[dict]] = {s: [] for s in SETTINGS}
        for r in range(rounds):
            for setting in SETTINGS:
                cmd = [sys.executable, "-m", "lerobot_focal.benchmarks.allocator", "--child", "--inputs", inp,
                       "--steps", str(steps), "--batch", str(batch)]
                proc = subprocess.run(cmd, env=_env(setting), capture_output=True, text=True, check=True)
                samples[setting].append(json.loads(proc.stdout.strip().splitlines()[-1]))
                print(f"[allocator] {inp}, round {r + 1}/{rounds}, {setting}: "
                      f"{samples[setting][-1]['s_per_step'] * 1e3:.0f} ms/step", flush=True)
        med = {s: statistics.median(x["s_per_step"] for x in samples[s]) for s in SETTINGS}
        fingerprints = {(x["loss"], x["checksum"]) for s in SETTINGS for x in samples[s]}
        result["inputs"][inp] = {"ms_per_step": {s: round(med[s] * 1e3, 1) for s in SETTINGS},
                                 "speedup": round(med[SETTINGS[0]] / med[SETTINGS[1]], 2),
                                 "bit_identical": len(fingerprints) == 1}
    out.mkdir(parents=True, exist_ok=True)
    (out / "allocator_cpu.json").write_text(json.dumps(result, indent=1))
    md = ["# glibc malloc settings and focal's CPU training step", "",
          f"`lerobot-focal-bench allocator`: median ms per step over {rounds} alternated child processes per "
          f"setting, {steps} timed steps each (batch {batch}, U-Net 32/64/128, one thread). MALLOC_ENV (grid) is "
          "`MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=4294967296`, what the grid gives its runs. "
          "Bit-identical: the same loss and weights after the steps under both settings.", "",
          f"| inputs | {SETTINGS[0]} | {SETTINGS[1]} | speed-up | bit-identical |", "|---|---|---|---|---|"]
    for inp, r in result["inputs"].items():
        md.append(f"| {inp} | {r['ms_per_step'][SETTINGS[0]]:.0f} | {r['ms_per_step'][SETTINGS[1]]:.0f} | "
                  f"{r['speedup']:.2f}× | {'yes' if r['bit_identical'] else 'NO'} |")
    (out / "allocator_cpu.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return result


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench allocator")
    p.add_argument("--inputs", nargs="+", choices=["pointcloud", "state"], default=["pointcloud", "state"])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--steps", type=int, default=8)
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.inputs[0], args.steps, args.batch)))
        return 0
    result = run(args.inputs, args.rounds, args.steps, args.batch, args.out)
    return 0 if all(r["bit_identical"] for r in result["inputs"].values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
