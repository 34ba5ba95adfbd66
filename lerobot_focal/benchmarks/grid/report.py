"""Render a grid's results: Markdown tables in the paper's layout, the issue's goals, and PNG plots.

Reads ``results.jsonl`` and ``grid.json`` from the results directory and writes ``report.md``, ``summary.json``,
``learning_curves.png``, ``success_bars.png`` and ``compounding_error.png`` next to them. Only ``ok`` records
count; a run with several ok records (rerun by hand) counts once, its latest.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from .methods import METHODS
from .metrics import mean_curve, mean_std
from .results import ResultsFile

GOAL_MARGIN = 0.05  # focal ≥ w/o FCO & LAS + 5 points


def _fmt(m: float, s: float | None = None, scale: float = 100.0, digits: int = 1) -> str:
    if m is None or math.isnan(m):
        return "–"
    if s is None or math.isnan(s):
        return f"{m * scale:.{digits}f}"
    return f"{m * scale:.{digits}f} ± {s * scale:.{digits}f}"


def aggregate(records: list[dict]) -> dict:
    """{method: {task: {metric: (mean, std), 'curve': ..., 'seeds': n}}, plus the task average per seed."""
    by = defaultdict(lambda: defaultdict(list))
    for r in records:
        by[r["method"]][r["task"]].append(r)
    out: dict = {}
    for method, tasks in by.items():
        out[method] = {}
        for task, runs in tasks.items():
            entry = {key: mean_std([r[key] for r in runs]) for key in (
                "success_top_k", "success_final", "atv", "ts_score", "compounding_error", "latency_ms", "nfe",
                "wall_s", "update_s_per_step")}
            entry["seeds"] = sorted(r["seed"] for r in runs)
            steps = [c["step"] for c in runs[0]["curve"]]
            entry["curve_steps"] = steps
            entry["curve_success"] = mean_curve([[c["success"] for c in r["curve"]] for r in runs]).tolist()
            entry["curve_success_std"] = np.std([[c["success"] for c in r["curve"]][: len(steps)] for r in runs],
                                                axis=0).tolist()
            entry["compounding_curve"] = mean_curve([r["compounding_curve"] for r in runs]).tolist()
            out[method][task] = entry
    return out


def _task_average_per_seed(records: list[dict], method: str, tasks: list[str], key: str) -> list[float]:
    """The development-set average of `key` for each seed that has every task (paper: mean ± std over seeds)."""
    per_seed = defaultdict(dict)
    for r in records:
        if r["method"] == method and r["task"] in tasks:
            per_seed[r["seed"]][r["task"]] = r[key]
    return [float(np.mean([v[t] for t in tasks])) for v in per_seed.values() if all(t in v for t in tasks)]


def _goals(records: list[dict], tasks: list[str], methods: list[str]) -> list[str]:
    lines = []

    def avg(method: str, key: str) -> float:
        return mean_std(_task_average_per_seed(records, method, tasks, key))[0]

    if "focal" not in methods:
        return ["- focal is not in this grid: no goals to check."]
    f = avg("focal", "success_top_k")
    if "wo_fco_las" in methods:
        b = avg("wo_fco_las", "success_top_k")
        ok = f >= b + GOAL_MARGIN
        lines.append(f"- focal ≥ w/o FCO & LAS + 5 points (top-5 success, task average): focal {f * 100:.1f} vs "
                     f"{b * 100:.1f} → **{'met' if ok else 'MISSED'}** ({(f - b) * 100:+.1f} points)")
        for key, name in (("atv", "ATV"), ("compounding_error", "open-loop compounding error")):
            fv, bv = avg("focal", key), avg("wo_fco_las", key)
            lines.append(f"- focal's {name} below w/o FCO & LAS: {fv:.4f} vs {bv:.4f} → "
                         f"**{'met' if fv < bv else 'MISSED'}**")
    if "diffusion" in methods:
        d = avg("diffusion", "success_top_k")
        lines.append(f"- focal ≥ diffusion (DDIM 10): {f * 100:.1f} vs {d * 100:.1f} → "
                     f"**{'met' if f >= d else 'MISSED'}**")
        lf, ld = avg("focal", "latency_ms"), avg("diffusion", "latency_ms")
        ratio = ld / lf if lf else math.nan
        lines.append(f"- latency per chunk ≥ 8× lower than diffusion DDIM 10: {lf:.1f} ms vs {ld:.1f} ms = "
                     f"{ratio:.1f}× → **{'met' if ratio >= 8 else 'MISSED'}** (NFE {avg('focal', 'nfe'):.0f} vs "
                     f"{avg('diffusion', 'nfe'):.0f}; the two U-Nets have the same channels, diffusion's horizon is "
                     "16 vs focal's 12)")
    return lines


def write_report(out_dir: Path) -> Path:
    out_dir = Path(out_dir)
    grid = json.loads((out_dir / "grid.json").read_text())
    records = list(ResultsFile(out_dir / "results.jsonl").ok().values())
    records = [r for r in records if r["task"] in grid["tasks"] and r["method"] in grid["methods"]]
    failed = [r for r in ResultsFile(out_dir / "results.jsonl").records()
              if r.get("status") == "failed" and r["key"] not in {x["key"] for x in records}]
    agg = aggregate(records)
    tasks = grid["tasks"]
    methods = [m for m in grid["methods"] if m in agg]
    preset = grid["preset"]
    label = {m: METHODS[m].label if m in METHODS else m for m in methods}

    md = [f"# Benchmark grid: preset `{preset['name']}`", "", preset["notes"], ""]
    if grid.get("overrides"):
        md += ["Overridden on the command line: " + ", ".join(f"{k}={v}" for k, v in grid["overrides"].items()), ""]
    md += [f"{len(records)} runs: tasks {', '.join(tasks)}; seeds {', '.join(map(str, grid['seeds']))}. "
           f"Score = mean of the top-{preset['top_k']} of {preset['steps'] // preset['eval_every']} evaluations "
           f"({preset['eval_episodes']} episodes every {preset['eval_every']} steps), then mean ± std over seeds "
           f"(success in %; one evaluation episode is {100 / preset['eval_episodes']:.0f} points). Wall times are "
           "those of this machine while the grid ran, other jobs included.", ""]
    if failed:
        md += [f"**{len(failed)} runs failed** and are not in the tables: "
               + ", ".join(sorted(r["key"] for r in failed)), ""]

    def table(title: str, key: str, scale: float, digits: int, note: str = "") -> list[str]:
        rows = [f"## {title}", ""] + ([note, ""] if note else [])
        rows.append("| Method | " + " | ".join(tasks) + " | Average |")
        rows.append("|---|" + "---|" * (len(tasks) + 1))
        for m in methods:
            cells = [_fmt(*agg[m][t][key], scale=scale, digits=digits) if t in agg[m] else "–" for t in tasks]
            avg = mean_std(_task_average_per_seed(records, m, tasks, key))
            rows.append(f"| {label[m]} | " + " | ".join(cells) + f" | {_fmt(*avg, scale=scale, digits=digits)} |")
        return rows + [""]

    md += table(f"Success, top-{preset['top_k']} (%)", "success_top_k", 100, 1)
    md += table("Success at the last evaluation (%)", "success_final", 100, 1)
    md += table("Action Total Variation of executed actions (↓)", "atv", 1, 4,
                "ATV of the final checkpoint's evaluation episodes (paper eq. for ATV).")
    md += table("Open-loop compounding error on held-out demos (↓)", "compounding_error", 1, 3,
                "Mean distance between integrated xyz actions of policy and expert along held-out episodes "
                "(positions start at the origin), recorded observations in.")
    md += table("TS score (↓)", "ts_score", 1, 4,
                "TS score = |TS_expert − TS_policy|, TS = mean ‖a_{t+1} − 2a_t + a_{t−1}‖ (CoLA's exact TS formula is not "
                "available to us; this is our stand-in of the same kind).")
    md += ["## Cost per run", "", "| Method | NFE per chunk | latency per chunk (ms, batch 1) | update (s/step) | "
           "wall time per run (min) |", "|---|---|---|---|---|"]
    for m in methods:
        vals = {k: mean_std([agg[m][t][k][0] for t in agg[m]]) for k in ("nfe", "latency_ms", "update_s_per_step",
                                                                         "wall_s")}
        md.append(f"| {label[m]} | {vals['nfe'][0]:.0f} | {vals['latency_ms'][0]:.1f} | "
                  f"{vals['update_s_per_step'][0]:.3f} | {vals['wall_s'][0] / 60:.1f} |")
    md += ["", "## Goals (issue 5), measured side by side in this grid", ""] + _goals(records, tasks, methods) + [""]
    md += ["## Plots", "", "![learning curves](learning_curves.png)", "", "![success](success_bars.png)", "",
           "![compounding error](compounding_error.png)", ""]
    (out_dir / "report.md").write_text("\n".join(md))
    (out_dir / "summary.json").write_text(json.dumps({"grid": grid, "aggregate": agg}, indent=1))
    _plots(out_dir, agg, records, tasks, methods, label, preset)
    return out_dir / "report.md"


def _plots(out_dir: Path, agg: dict, records: list[dict], tasks: list[str], methods: list[str], label: dict,
           preset: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(len(tasks), 3)
    rows = -(-len(tasks) // cols)
    for name, key, ylabel in (("learning_curves", "curve", "success (mean over seeds)"),
                              ("compounding_error", "compounding", "compounding error (open loop)")):
        fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
        for ax, task in zip(axes.flat, tasks):
            for i, m in enumerate(methods):
                if task not in agg[m]:
                    continue
                e = agg[m][task]
                if key == "curve":
                    x, y, s = np.array(e["curve_steps"]), np.array(e["curve_success"]), np.array(e["curve_success_std"])
                    ax.plot(x, y, marker=".", color=f"C{i}", label=label[m])
                    ax.fill_between(x, y - s, y + s, color=f"C{i}", alpha=0.15)
                    ax.set_ylim(-0.05, 1.05)
                    ax.set_xlabel("training step")
                else:
                    y = np.array(e["compounding_curve"])
                    ax.plot(np.arange(1, len(y) + 1), y, color=f"C{i}", label=label[m])
                    ax.set_xlabel("step along held-out episode")
            ax.set_title(task)
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3)
        for ax in list(axes.flat)[len(tasks):]:
            ax.axis("off")
        axes.flat[0].legend(fontsize=7)
        fig.suptitle(f"preset {preset['name']}")
        fig.tight_layout()
        fig.savefig(out_dir / f"{name}.png", dpi=100)
        plt.close(fig)

    fig, ax = plt.subplots(figsize=(1.6 + 0.9 * len(tasks) * len(methods) / 2, 3.6))
    groups = tasks + ["Average"]
    width = 0.8 / max(len(methods), 1)
    for i, m in enumerate(methods):
        means, stds = [], []
        for t in tasks:
            mu, sd = agg[m][t]["success_top_k"] if t in agg[m] else (math.nan, math.nan)
            means.append(mu)
            stds.append(sd)
        mu, sd = mean_std(_task_average_per_seed(records, m, tasks, "success_top_k"))
        means.append(mu)
        stds.append(sd)
        x = np.arange(len(groups)) + (i - (len(methods) - 1) / 2) * width
        ax.bar(x, np.array(means) * 100, width, yerr=np.array(stds) * 100, capsize=2, color=f"C{i}", label=label[m])
    ax.set_xticks(np.arange(len(groups)), groups, rotation=20)
    ax.set_ylabel(f"success, top-{preset['top_k']} (%)")
    ax.set_title(f"preset {preset['name']}: mean ± std over seeds")
    ax.legend(fontsize=7)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out_dir / "success_bars.png", dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="lerobot-focal-bench report", description=__doc__)
    parser.add_argument("--out", type=Path, required=True, help="the grid's --out directory")
    args = parser.parse_args(argv)
    print(write_report(args.out).read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
