"""A learning-rate sweep through the grid: each (method, lr) is one grid invocation, one task, one seed.

    lerobot-focal-bench lr-sweep --preset cpu_fair --task disassemble --seed 0 \\
        --runs diffusion_ema=1e-4,3e-4,1e-3 --runs act=1e-5,1e-4 \\
        --out docs/benchmarks/lr_sweep_fair --work outputs/bench

Every learning rate gets its own results directory ``--out/lr_<lr>/`` (a grid with ``--lr``: every method of it
at that rate, its runs in their own folders under ``--work``), so methods swept at the same rate share one
report. The runs go one after another (one `lerobot-train` at a time), each as its own
`lerobot-focal-bench grid` process, in the order given; rerunning the same command skips the finished runs and
continues an interrupted one from its last checkpoint, as the grid does. After every invocation the sweep
writes ``--out/summary.json`` and ``--out/summary.md``: per method and rate the paper's top-5 (or the
fixed-episode one, as the preset evaluates), the last periodic evaluation, the final checkpoint on fresh
episodes and the learning curve; and per method the rate it picks.

Choice of the rate: the highest success of the final checkpoint on the fresh episodes (the grid's unbiased
number: top-k picks checkpoints on the episodes it reports), ties broken by the top-k, then by the lower rate.
With ``--summary-only`` nothing runs; the summary is rewritten from what has landed.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from ....console import doc_parser
from ..results import ResultsFile, run_key


def parse_runs(specs: list[str]) -> list[tuple[str, float]]:
    """``method=lr1,lr2`` items → [(method, lr), …] in the order given."""
    runs: list[tuple[str, float]] = []
    for spec in specs:
        method, sep, rates = spec.partition("=")
        if not sep or not method.strip() or not rates.strip():
            raise argparse.ArgumentTypeError(f"expected METHOD=LR[,LR...], e.g. diffusion_ema=1e-4,3e-4; got {spec!r}")
        for rate in rates.split(","):
            try:
                lr = float(rate)
            except ValueError:
                raise argparse.ArgumentTypeError(f"not a learning rate: {rate!r} in {spec!r}") from None
            if not lr > 0:
                raise argparse.ArgumentTypeError(f"a learning rate must be > 0; got {rate!r} in {spec!r}")
            runs.append((method.strip(), lr))
    return runs


def lr_folder(lr: float) -> str:
    return f"lr_{lr:g}"


def grid_argv(args: argparse.Namespace, method: str, lr: float) -> list[str]:
    return ["grid", "--preset", args.preset, "--tasks", args.task, "--methods", method, "--seeds", str(args.seed),
            "--lr", repr(lr), "--out", str(args.out / lr_folder(lr)), "--work", str(args.work), *args.grid_args]


def summarize(out: Path, task: str, seed: int, runs: list[tuple[str, float]]) -> dict:
    """What has landed, per method and rate, and each method's chosen rate (module docstring)."""
    rows = []
    for method, lr in runs:
        records = ResultsFile(out / lr_folder(lr) / "results.jsonl").ok() if (out / lr_folder(lr)).exists() else {}
        r = records.get(run_key(task, method, seed))
        row = {"method": method, "lr": lr, "status": "done" if r else "to do"}
        if r:
            row.update({k: getattr(r, k) for k in ("success_top_k", "periodic_eval", "success_final", "success_fresh",
                                              "fresh_episodes", "latency_ms", "nfe", "n_params",
                                              "update_s_per_step", "wall_s")})
            row["curve"] = [round(c["success"], 3) for c in r.curve]
        rows.append(row)
    chosen = {}
    for method in dict.fromkeys(m for m, _ in runs):
        done = [r for r in rows if r["method"] == method and r["status"] == "done"]
        complete = len(done) == sum(m == method for m, _ in runs)
        if done:
            best = max(done, key=lambda r: (r.get("success_fresh") or 0.0, r["success_top_k"], -r["lr"]))
            chosen[method] = {"lr": best["lr"], "complete": complete}
    return {"task": task, "seed": seed, "rule": "highest fresh-episode success of the final checkpoint, then top-k, "
            "then the lower rate", "runs": rows, "chosen": chosen}


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.0f}"


def render(summary: dict) -> str:
    lines = [f"# Learning-rate sweep: {summary['task']}, seed {summary['seed']}", "",
             "Success in %. top-k: the run's periodic evaluations (fresh placements at each: the paper's estimator, "
             "or the same ones each time: fixed, as the preset says); fresh: the final checkpoint on its fresh "
             "episodes. Written by `lerobot-focal-bench lr-sweep` (docstring: how to rerun).", "",
             "| method | lr | top-k | last evaluation | fresh (episodes) | curve (every evaluation) "
             "| latency ms/chunk | NFE | s/step | wall min |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in summary["runs"]:
        if r["status"] != "done":
            lines.append(f"| {r['method']} | {r['lr']:g} | to do | | | | | | | |")
            continue
        curve = " ".join(_pct(x) for x in r["curve"])
        lines.append(
            f"| {r['method']} | {r['lr']:g} | {_pct(r['success_top_k'])} ({r.get('periodic_eval') or 'fixed'}) | "
            f"{_pct(r['success_final'])} | {_pct(r.get('success_fresh'))} ({r.get('fresh_episodes') or 0}) | {curve} | "
            f"{r['latency_ms']:.1f} | {r['nfe']:g} | {r['update_s_per_step'] or float('nan'):.3f} | "
            f"{r['wall_s'] / 60:.0f} |")
    lines += ["", f"Rule: {summary['rule']}.", ""]
    for method, c in summary["chosen"].items():
        state = "" if c["complete"] else " (so far: not every rate has landed)"
        lines.append(f"- **{method}**: lr {c['lr']:g}{state}")
    return "\n".join(lines) + "\n"


def write_summary(out: Path, task: str, seed: int, runs: list[tuple[str, float]]) -> dict:
    summary = summarize(out, task, seed, runs)
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    (out / "summary.md").write_text(render(summary))
    return summary


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench lr-sweep")
    p.add_argument("--preset", default="cpu_fair")
    p.add_argument("--task", required=True, help="one MetaWorld v3 task")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--runs", action="append", required=True, metavar="METHOD=LR[,LR...]",
                   help="a method and its rates; repeat for more methods (runs go in the order given)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--work", type=Path, default=Path("outputs/bench"))
    p.add_argument("--summary-only", action="store_true", help="rewrite the summary from what has landed; run nothing")
    p.add_argument("grid_args", nargs="*", help="after --: more arguments for every grid invocation")
    args = p.parse_args(argv)
    try:
        runs = parse_runs(args.runs)
    except argparse.ArgumentTypeError as e:
        p.error(str(e))
    status = 0
    if not args.summary_only:
        for method, lr in runs:
            command = [sys.executable, "-m", "lerobot_focal.benchmarks.cli", *grid_argv(args, method, lr)]
            print(f"[lr_sweep] {method} at lr {lr:g}: {' '.join(command[3:])}", flush=True)
            try:
                rc = subprocess.run(command).returncode
            except KeyboardInterrupt:
                print("[lr_sweep] interrupted: rerun the same command to continue", flush=True)
                return 130
            write_summary(args.out, args.task, args.seed, runs)
            if rc == 130 or rc < 0:  # the grid was stopped: stop the sweep too
                print("[lr_sweep] the grid was stopped: rerun the same command to continue", flush=True)
                return 130
            status = status or rc
    summary = write_summary(args.out, args.task, args.seed, runs)
    print(render(summary), flush=True)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
