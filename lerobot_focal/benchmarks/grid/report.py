"""Render a grid's results: Markdown tables in the paper's layout, the issue's goals, and PNG plots.

Reads ``results.jsonl`` and ``grid.json`` from the results directory and writes ``report.md``, ``summary.json``,
``learning_curves.png``, ``success_bars.png`` and ``compounding_error.png`` next to them. Only ``ok`` records
count; a run with several ok records (rerun by hand) counts once, its latest.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import replace
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from ...figures import save_png
from ..paper_results import PAPER_FOCAL_METAWORLD as PAPER_FOCAL_TOP5
from .grid_presets import capped_seeds
from .methods import METHODS, given
from .metrics import mean_curve, mean_std, paired_difference
from .results import ResultsFile, RunRecord

PAPER_MARGIN = 10.0  # points: focal's top-5 within this of the paper on each task
#: focal's latency per chunk within this factor of a method's, at the same inputs (one network pass each for ACT)
LATENCY_GOALS = {"act": 1.5}
METRIC_KEYS = ("success_top_k", "success_top_k_paper", "success_top_k_fixed", "success_rescore_mean",
               "success_final", "success_fresh", "atv", "atv_fresh", "ts_score",
               "compounding_error", "latency_ms", "nfe", "wall_s", "final_eval_s", "update_s_per_step")


def _fmt(m: float, s: float | None = None, scale: float = 100.0, digits: int = 1) -> str:
    if m is None or math.isnan(m):
        return "–"
    if s is None or math.isnan(s):
        return f"{m * scale:.{digits}f}"
    return f"{m * scale:.{digits}f} ± {s * scale:.{digits}f}"


def _cell(mean: float, std: float, n: int, n_grid_seeds: int, scale: float, digits: int) -> str:
    """A table cell: mean ± std over `n` seeds, saying how many seeds when fewer than the grid's have finished.

    A spread over one seed would print as "± 0.0", which reads as a measured agreement; it is left out."""
    if n >= n_grid_seeds:
        return _fmt(mean, std, scale=scale, digits=digits)
    text = _fmt(mean, std if n > 1 else None, scale=scale, digits=digits)
    return text if text == "–" else f"{text} ({n} seed{'s' if n > 1 else ''})"


def with_estimators(records: list[RunRecord], rescored: dict[str, dict]) -> list[RunRecord]:
    """Each record with the paper's estimator and today's beside each other (see docs/benchmarks.md).

    ``success_top_k_paper``: top-k of periodic evaluations on fresh placements (a run with ``periodic_eval``
    "fresh": DP3's runner), else top-k of the re-score's blocks of the final checkpoint when ``rescore.json``
    has the run, else absent. ``success_top_k_fixed``: top-k of periodic evaluations on the same placements every
    time, which a "fresh" run does not have (n/a: evaluating both ways would double the evaluation cost).
    ``success_rescore_mean``: the re-score's mean over all its episodes."""
    out = []
    for r in records:
        fresh = r.periodic_eval == "fresh"
        again = rescored.get(r.key)
        out.append(replace(
            r,
            success_top_k_paper=r.success_top_k if fresh else again["top_k"] if again else None,
            success_top_k_fixed=None if fresh else r.success_top_k,
            success_rescore_mean=again["mean"] if again else None,
        ))
    return out


def aggregate(records: list[RunRecord]) -> dict:
    """{method: {task: {metric: (mean, std), 'curve': ..., 'seeds': n}}, plus the task average per seed."""
    by = defaultdict(lambda: defaultdict(list))
    for r in records:
        by[r.method][r.task].append(r)
    out: dict = {}
    for method, tasks in by.items():
        out[method] = {}
        for task, runs in tasks.items():
            entry = {key: mean_std([r.value(key) for r in runs]) for key in METRIC_KEYS}
            entry["seeds"] = sorted(r.seed for r in runs)
            steps = [c["step"] for c in runs[0].curve]
            entry["curve_steps"] = steps
            entry["curve_success"] = mean_curve([[c["success"] for c in r.curve] for r in runs]).tolist()
            entry["curve_success_std"] = np.std([[c["success"] for c in r.curve][: len(steps)] for r in runs],
                                                axis=0).tolist()
            entry["compounding_curve"] = mean_curve([r.compounding_curve for r in runs]).tolist()
            out[method][task] = entry
    return out


def _task_average_per_seed(records: list[RunRecord], method: str, tasks: list[str], key: str) -> list[float]:
    """The development-set average of `key` for each seed that has every task (paper: mean ± std over seeds)."""
    per_seed = defaultdict(dict)
    for r in records:
        if r.method == method and r.task in tasks and getattr(r, key) is not None:
            per_seed[r.seed][r.task] = getattr(r, key)
    return [float(np.mean([v[t] for t in tasks])) for v in per_seed.values() if all(t in v for t in tasks)]


def _pairs(records: list[RunRecord], a: str, b: str, key: str, tasks: list[str]) -> tuple[list[float], list[float]]:
    """`key` of methods a and b on every (task, seed) both have: the pairs of a paired comparison."""
    by = {(r.method, r.task, r.seed): getattr(r, key) for r in records}
    common = sorted((t, s) for (m, t, s) in by if m == a and t in tasks and (b, t, s) in by)
    common = [(t, s) for t, s in common if by[(a, t, s)] is not None and by[(b, t, s)] is not None]
    return [by[(a, t, s)] for t, s in common], [by[(b, t, s)] for t, s in common]


#: Paired contrasts that isolate one module each, shown when the grid has both methods: (a, b, what a − b says).
MODULE_CONTRASTS: tuple[tuple[str, str, str], ...] = (
    ("diffusion_fco", "diffusion", "FCO added to diffusion (the paper's Table 2 question)"),
    ("wo_las", "wo_fco_las",
     "FCO (one flow segment) instead of FlowPolicy's two-segment objective, both without LAS"),
    ("focal_pc", "focal", "the paper's 512-point cloud instead of the 39-d object poses (the input, not the method)"),
)


def _paired_cells(records: list[RunRecord], tasks: list[str], a: str, b: str, keys: list[tuple]) -> list[str] | None:
    """One table row's cells: a − b per key, with its interval and a's wins / ties / losses, n/a for a key no pair
    has (records older than the key); None if no key has a pair."""
    cells = []
    for key, _ in keys:
        d = paired_difference(*_pairs(records, a, b, key, tasks))
        if d["n"] == 0:
            cells.append("n/a")
            continue
        ci = "" if math.isnan(d["lo"]) else f" [{d['lo'] * 100:+.1f}, {d['hi'] * 100:+.1f}]"
        cells.append(f"{d['mean'] * 100:+.1f}{ci} (n={d['n']}; {d['wins']}/{d['ties']}/{d['losses']})")
    return None if all(c == "n/a" for c in cells) else cells


def _rival(method: str) -> str:
    """The focal a method is compared with (``Method.rival``: the one on the same inputs)."""
    return METHODS[method].rival if method in METHODS else "focal"


def _paired_table(
    records: list[RunRecord], tasks: list[str], methods: list[str], label: dict, keys: list[tuple]
) -> list[str]:
    if "focal" not in methods:
        return []
    header = "| " + " | ".join(name for _, name in keys) + " |"
    rule = "|---|" + "---|" * len(keys)
    rows = ["## Paired comparisons: focal − method", "",
            "Differences in success points over the (task, seed) pairs both methods have (same demos, same "
            "evaluation episodes), mean with a 95 % Student-t interval, and focal's wins / ties / losses.", "",
            "| Method " + header, rule]
    method_rows = []
    for m in methods:
        rival = _rival(m)
        cells = None if m == "focal" or rival not in methods else _paired_cells(records, tasks, rival, m, keys)
        name = label[m] if rival == "focal" else f"{label[m]} (against {label[rival]})"
        method_rows += [f"| {name} | " + " | ".join(cells) + " |"] if cells else []
    rows = rows + method_rows if method_rows else []
    contrasts = [(a, b, what) for a, b, what in MODULE_CONTRASTS if a in methods and b in methods]
    module_rows = []
    for a, b, what in contrasts:
        cells = _paired_cells(records, tasks, a, b, keys)
        if cells:
            module_rows.append(f"| {label[a]} − {label[b]}: {what} | " + " | ".join(cells) + " |")
    if module_rows:
        rows += ([""] if rows else []) + ["## Paired comparisons: what one module adds", "",
                 "The same paired differences between two methods that differ in one module only (wins / ties / "
                 "losses are the first method's).", "", "| Contrast " + header, rule, *module_rows]
    return rows + [""] if rows else []


def _point_cloud_goal(records: list[RunRecord], tasks: list[str], label: dict) -> list[str]:
    """focal on the paper's input, beside low-dim focal on the same seeds, and against the paper per task.

    The paper's numbers are for point clouds, so this is the like-for-like comparison with them; it is reported,
    not a goal of its own: the goal is only that it is shown beside low-dim focal."""
    d = paired_difference(*_pairs(records, "focal_pc", "focal", "success_top_k", tasks))
    if d["n"] == 0:
        return []
    seeds = sorted({r.seed for r in records if r.method == "focal_pc"})
    ci = "" if math.isnan(d["lo"]) else f", 95 % interval [{d['lo'] * 100:+.1f}, {d['hi'] * 100:+.1f}]"
    lines = [f"- {label['focal_pc']} beside low-dim focal (top-5, paired over {d['n']} task-seed pairs, seeds "
             f"{', '.join(map(str, seeds))}): {d['mean'] * 100:+.1f} points{ci}"
             f"; point clouds better / level / worse in {d['wins']}/{d['ties']}/{d['losses']} → **reported**"]
    for t in (t for t in tasks if t in PAPER_FOCAL_TOP5):
        mine = mean_std([r.success_top_k for r in records if r.method == "focal_pc" and r.task == t])[0]
        if not math.isnan(mine):
            lines.append(f"  - on {t}: {mine * 100:.1f} vs the paper's {PAPER_FOCAL_TOP5[t]:.1f} "
                         f"({mine * 100 - PAPER_FOCAL_TOP5[t]:+.1f})")
    return lines


def _goals(records: list[RunRecord], tasks: list[str], methods: list[str], label: dict) -> list[str]:
    """The benchmark's goals, each with its numbers and met / MISSED; nothing here tunes the protocol."""
    if "focal" not in methods:
        return ["- focal is not in this grid: no goals to check."]
    lines = []

    def avg(method: str, key: str) -> float:
        return mean_std(_task_average_per_seed(records, method, tasks, key))[0]

    paper_tasks = [t for t in tasks if t in PAPER_FOCAL_TOP5]
    for t in paper_tasks:
        mine = mean_std([r.success_top_k for r in records if r.method == "focal" and r.task == t])[0]
        if math.isnan(mine):
            continue
        gap = mine * 100 - PAPER_FOCAL_TOP5[t]
        lines.append(f"- focal within {PAPER_MARGIN:.0f} points of the paper on {t}: {mine * 100:.1f} vs "
                     f"{PAPER_FOCAL_TOP5[t]:.1f} ({gap:+.1f}) → **{'met' if gap >= -PAPER_MARGIN else 'MISSED'}**")
    if paper_tasks == tasks:
        f = avg("focal", "success_top_k")
        paper = float(np.mean([PAPER_FOCAL_TOP5[t] for t in tasks]))
        if not math.isnan(f):
            lines.append(f"- focal's average ≥ the paper's ({paper:.1f}): {f * 100:.1f} → "
                         f"**{'met' if f * 100 >= paper else 'MISSED'}**")
        else:
            per_seed: dict[int, set[str]] = {}
            for r in records:
                if r.method == "focal" and r.task in tasks:
                    per_seed.setdefault(r.seed, set()).add(r.task)
            most = max(map(len, per_seed.values()), default=0)
            lines.append(f"- focal's average ≥ the paper's ({paper:.1f}): not measured yet (an average needs every "
                         f"task on one seed; focal has at most {most} of {len(tasks)} tasks on a seed)")
    if "focal_pc" in methods:
        lines += _point_cloud_goal(records, tasks, label)
    baselines = [m for m in methods if m != "focal" and not (m in METHODS and METHODS[m].variant_of == "focal")]
    def who(rival: str) -> str:
        return "focal" if rival == "focal" else label.get(rival, rival)

    for m in baselines:
        rival = _rival(m)
        for key, number in (("success_top_k", "top-5"), ("success_fresh", "final checkpoint, fresh episodes")):
            d = paired_difference(*_pairs(records, rival, m, key, tasks))
            if d["n"] == 0:
                continue
            ci = "" if math.isnan(d["lo"]) else f", 95 % interval [{d['lo'] * 100:+.1f}, {d['hi'] * 100:+.1f}]"
            lines.append(f"- {who(rival)} ≥ {label[m]} ({number}, paired over {d['n']} task-seed pairs): "
                         f"{d['mean'] * 100:+.1f} points{ci} → {_verdict(d)}")

    for m in (b for b in baselines if b in METHODS and METHODS[b].policy_type != "focal"):
        rival = _rival(m)
        lf, lm = cost_per_run(records, rival, "latency_ms"), cost_per_run(records, m, "latency_ms")
        if math.isnan(lm) or math.isnan(lf):
            continue
        line = (f"- latency per chunk: {who(rival)} {lf:.1f} ms vs {label[m]} {lm:.1f} ms, a ratio of {lf / lm:.2f} "
                f"(NFE {cost_per_run(records, rival, 'nfe'):.0f} vs {cost_per_run(records, m, 'nfe'):.0f})")
        if m in LATENCY_GOALS:  # a goal of the benchmark: focal's latency within this factor of the method's
            factor = LATENCY_GOALS[m]
            line += f" → within {factor:g}× of {label[m]}'s: **{'met' if lf <= factor * lm else 'MISSED'}**"
        lines.append(line)
    return lines


def _verdict(d: dict) -> str:
    """met / MISSED on the mean of a paired difference, and whether its interval already shows it."""
    if math.isnan(d["lo"]):
        return f"**{'met' if d['mean'] >= 0 else 'MISSED'}** on the mean (one pair: no interval yet)"
    if d["mean"] < 0:
        return "**MISSED**" + (" (the interval still includes 0)" if d["hi"] >= 0 else "")
    return "**met**" if d["lo"] > 0 else "**met** on the mean (the interval still includes 0: not yet shown)"


def _estimators_table(
    records: list[RunRecord], tasks: list[str], methods: list[str], label: dict, preset: dict
) -> list[str]:
    """One cell per method and task with the three numbers side by side (means over seeds, in %)."""
    k = preset["top_k"]

    def cell(runs: list[RunRecord]) -> str:
        vals = [mean_std([r.value(key) for r in runs])[0]
                for key in ("success_top_k_paper", "success_top_k_fixed", "success_fresh")]
        return " / ".join("n/a" if math.isnan(v) else f"{v * 100:.1f}" for v in vals)

    rows = ["## Three estimators: paper's top-5 / fixed-episode top-5 / final checkpoint on fresh episodes (%)", "",
            f"Per cell, means over seeds: top-{k} with fresh placements at every evaluation (the paper's estimator, "
            "DP3's runner; for a grid whose periodic evaluations reuse their placements, top-"
            f"{k} of the re-score's blocks of the final checkpoint, `lerobot-focal-bench rescore`), top-{k} of "
            "periodic evaluations on the same placements every time (n/a for runs evaluated on fresh placements), "
            "and the final checkpoint on fresh episodes. n/a: not measured.", "",
            "| Method | " + " | ".join(tasks) + " |", "|---|" + "---|" * len(tasks)]
    for m in methods:
        cells = [cell(runs) if (runs := [r for r in records if r.method == m and r.task == t]) else "–"
                 for t in tasks]
        rows.append(f"| {label[m]} | " + " | ".join(cells) + " |")
    rescored = [r for r in records if r.success_rescore_mean is not None]
    if rescored:
        rows += ["", "The re-score's mean over all its episodes (same checkpoints): "
                 + ", ".join(f"{r.key.replace('|', ' · ')} {r.success_rescore_mean * 100:.1f}"
                             for r in sorted(rescored, key=lambda r: r.key))]
    return rows + [""]


def summary_table(records: list[RunRecord], grid: dict) -> dict:
    """Per method and task: the protocol's numbers in one flat record (summary.json's "methods")."""
    preset = grid["preset"]
    out: dict = {}
    for m in grid["methods"]:
        for t in grid["tasks"]:
            runs = [r for r in records if r.method == m and r.task == t]
            if not runs:
                continue
            top5, top5_std = mean_std([r.success_top_k for r in runs])
            paper, paper_std = mean_std([r.value("success_top_k_paper") for r in runs])
            fixed, fixed_std = mean_std([r.value("success_top_k_fixed") for r in runs])
            fresh, fresh_std = mean_std([r.value("success_fresh") for r in runs])
            out.setdefault(m, {})[t] = {
                "top5_mean": top5, "top5_std": top5_std,
                # The paper's estimator (fresh placements at every evaluation, or the re-score's blocks) and
                # today's top-5 on the same placements at every evaluation (None where a run has no such number).
                "top5_paper_mean": paper, "top5_paper_std": paper_std,
                "top5_fixed_mean": fixed, "top5_fixed_std": fixed_std,
                "periodic_eval": sorted({r.periodic_eval for r in runs}),
                "rescore_mean": mean_std([r.value("success_rescore_mean") for r in runs])[0],
                "final_mean": fresh, "final_std": fresh_std,
                "last_eval_mean": mean_std([r.success_final for r in runs])[0],
                "n_evals": len(runs[0].curve), "episodes_per_eval": preset["eval_episodes"],
                "final_episodes": (runs[0].fresh_episodes or 0),
                "seeds": sorted(r.seed for r in runs), "steps": preset["steps"],
            }
    return out


def elapsed_s(records: list[RunRecord]) -> float:
    """Seconds during which at least one run of the grid was going: the union of the runs' intervals, so runs
    that overlapped (``--jobs`` > 1) count once and the gaps between grid invocations not at all. A record
    without ``started_at`` (written before it was recorded) starts its training and final evaluation before it
    finished. A run resumed after an interruption counts the spans it kept (``spans``), not the time between."""
    spans = []
    for r in records:
        if r.spans:
            spans += [(datetime.fromisoformat(a), datetime.fromisoformat(b)) for a, b in r.spans]
            continue
        if r.finished_at is None:
            continue
        end = datetime.fromisoformat(r.finished_at)
        if r.started_at:
            start = datetime.fromisoformat(r.started_at)
        else:
            start = end - timedelta(seconds=(r.wall_s or 0.0) + (r.final_eval_s or 0.0))
        spans.append((start, end))
    total, reach = 0.0, None
    for start, end in sorted(spans):
        if reach is not None and start < reach:
            start = reach
        if end > start:
            total += (end - start).total_seconds()
        reach = end if reach is None else max(reach, end)
    return total


def write_report(out_dir: Path) -> Path:
    out_dir = Path(out_dir)
    grid = json.loads((out_dir / "grid.json").read_text())
    records = list(ResultsFile(out_dir / "results.jsonl").ok().values())
    records = [r for r in records if r.task in grid["tasks"] and r.method in grid["methods"]]
    rescore_path = out_dir / "rescore.json"
    records = with_estimators(records, json.loads(rescore_path.read_text()) if rescore_path.exists() else {})
    failed = [r for r in ResultsFile(out_dir / "results.jsonl").records()
              if r.status == "failed" and r.key not in {x.key for x in records}]
    agg = aggregate(records)
    tasks = grid["tasks"]
    methods = [m for m in grid["methods"] if m in agg]
    preset = grid["preset"]
    label = {m: METHODS[m].label if m in METHODS else m for m in methods}

    md = [f"# Benchmark grid: preset `{preset['name']}`", "", preset["notes"], ""]
    caps = preset.get("seed_caps", ())  # absent from grids recorded before presets could cap a method's seeds

    def grid_seeds(method: str) -> list[int]:
        return capped_seeds(caps, method, grid["seeds"])

    todo = len(grid["tasks"]) * sum(len(grid_seeds(m)) for m in grid["methods"]) - len(records)
    hours = sum((r.wall_s or 0.0) + (r.final_eval_s or 0.0) for r in records) / 3600
    md += [f"Wall time of the {len(records)} finished runs: {elapsed_s(records) / 3600:.1f} h during which the grid "
           f"had runs going ({hours:.1f} h of training and evaluation summed over the runs, which overlap with "
           "`--jobs` > 1; other work shared the machine)"
           + (f"; {todo} {'run' if todo == 1 else 'runs'} of the grid {'is' if todo == 1 else 'are'} still to do "
              "(rerun the grid command to continue)." if todo > 0 else ".")
           , ""]
    resumed = [r for r in records if r.resumed_from_steps]
    if resumed:
        md += [f"{len(resumed)} of the runs continued from a checkpoint after an interruption (LeRobot's resume; "
               f"{sum((r.lost_s or 0.0) for r in resumed) / 60:.1f} min of work after their checkpoints was "
               "redone and is not counted above); their records list the steps they resumed from.", ""]
    if grid.get("overrides"):
        md += ["Overridden on the command line: " + ", ".join(f"{k}={v}" for k, v in grid["overrides"].items()), ""]
    capped = "".join(f" ({label.get(m, m)}: {', '.join(map(str, grid_seeds(m)))})" for m, _ in caps
                     if m in grid["methods"])
    md += [f"{len(records)} runs: tasks {', '.join(tasks)}; seeds {', '.join(map(str, grid['seeds']))}{capped}. "
           f"Score = mean of the top-{preset['top_k']} of {preset['steps'] // preset['eval_every']} evaluations "
           f"({preset['eval_episodes']} episodes every {preset['eval_every']} steps), then mean ± std over seeds "
           f"(success in %; one evaluation episode is {100 / preset['eval_episodes']:.0f} points); a cell that "
           "has fewer seeds so far says how many. Wall times are those of the machine the grid ran on, other "
           "jobs included.", ""]
    if failed:
        md += [f"**{len(failed)} runs failed** and are not in the tables: "
               + ", ".join(sorted(r.key for r in failed)), ""]

    def table(title: str, key: str, scale: float, digits: int, note: str = "", extra: list[str] = ()) -> list[str]:
        rows = [f"## {title}", ""] + ([note, ""] if note else [])
        rows.append("| Method | " + " | ".join(tasks) + " | Average |")
        rows.append("|---|" + "---|" * (len(tasks) + 1))
        for m in methods:
            n_seeds = len(grid_seeds(m))
            cells = [_cell(*agg[m][t][key], len(agg[m][t]["seeds"]), n_seeds, scale, digits) if t in agg[m]
                     else "–" for t in tasks]
            per_seed = _task_average_per_seed(records, m, tasks, key)
            avg = _cell(*mean_std(per_seed), len(per_seed), n_seeds, scale, digits)
            rows.append(f"| {label[m]} | " + " | ".join(cells) + f" | {avg} |")
        return rows + list(extra) + [""]

    paper_row = []
    if all(t in PAPER_FOCAL_TOP5 for t in tasks):
        paper_row = ["| *FocalPolicy, paper (512-pt clouds, 47k steps)* | "
                     + " | ".join(f"*{PAPER_FOCAL_TOP5[t]:.1f}*" for t in tasks)
                     + f" | *{np.mean([PAPER_FOCAL_TOP5[t] for t in tasks]):.1f}* |"]
    md += table(f"Success, top-{preset['top_k']} (%)", "success_top_k", 100, 1, extra=paper_row)
    if any(r.success_fresh is not None for r in records):
        n_fresh = max((r.fresh_episodes or 0) for r in records)
        md += table(f"Success of the final checkpoint on {n_fresh} fresh episodes (%)", "success_fresh", 100, 1,
                    "Episodes with seeds no periodic evaluation, demo or held-out episode used. Top-k picks the best "
                    "checkpoints on the episodes it reports, so it is optimistic; this number is not.")
    md += _estimators_table(records, tasks, methods, label, preset)
    md += table("Success at the last periodic evaluation (%)", "success_final", 100, 1)
    md += table("Action Total Variation of executed actions (↓)", "atv", 1, 4,
                "ATV of the final checkpoint's evaluation episodes (paper eq. for ATV).")
    md += table("Open-loop compounding error on held-out demos (↓)", "compounding_error", 1, 3,
                "Mean distance between integrated xyz actions of policy and expert along held-out episodes "
                "(positions start at the origin), recorded observations in.")
    md += table("TS score (↓)", "ts_score", 1, 4,
                "TS score = |TS_expert − TS_policy|, TS = mean ‖a_{t+1} − 2a_t + a_{t−1}‖ (CoLA's exact TS formula "
                "is not available to us; this is our stand-in of the same kind).")
    md += _given_table(methods, label, preset, agg)
    md += ["## Cost per run", "", "NFE, latency and update time: the median over a method's runs (every task feeds "
           "the network the same shapes; a run timed while the machine was slow does not move it); wall time: the "
           "mean over tasks. Torch threads per run: the preset's, or the OMP_NUM_THREADS the grid was started "
           "with (a run alone on the machine may use every core); – where the record predates the field.", "",
           "| Method | NFE per chunk | latency per chunk (ms, batch 1) | update (s/step) | "
           "wall time per run (min) | torch threads |", "|---|---|---|---|---|---|"]
    ranges = {m: _update_range(records, m) for m in methods}
    for m in methods:
        vals = {k: cost_per_run(records, m, k) for k in ("nfe", "latency_ms", "update_s_per_step", "wall_s")}
        threads = sorted({r.torch_threads for r in records if r.method == m and r.torch_threads is not None})
        low, high = ranges[m]
        spread = f" ({low:.3f}–{high:.3f})" if high > SPEED_SPREAD * low else ""
        md.append(f"| {label[m]} | {vals['nfe']:.0f} | {vals['latency_ms']:.1f} | "
                  f"{vals['update_s_per_step']:.3f}{spread} | {vals['wall_s'] / 60:.1f} | "
                  f"{', '.join(map(str, threads)) or '–'} |")
    if any(high > SPEED_SPREAD * low for low, high in ranges.values()):
        md += ["", f"A method whose update time varies by more than {SPEED_SPREAD:g}× between its runs (its range in "
               "brackets) ran on a machine whose speed changed between sessions (other jobs, another host): wall "
               "times, the learning-efficiency minutes included, compare methods only across runs that ran side "
               "by side; samples and success do not depend on it."]
    md += [""] + _paired_table(records, tasks, methods, label, [("success_top_k", f"top-{preset['top_k']}"),
                                                               ("success_fresh", "final, fresh episodes")])
    md += ["## Goals, measured side by side in this grid", ""] + _goals(records, tasks, methods, label) + [""]
    md += ["## Plots", "", "![learning curves](learning_curves.png)", "", "![success](success_bars.png)", "",
           "![compounding error](compounding_error.png)", ""]
    md += _learning_efficiency_section(records, tasks, methods, label, preset)
    md += _diagnostics(out_dir)
    (out_dir / "report.md").write_text("\n".join(md))
    summary = {"grid": grid, "methods": summary_table(records, grid), "aggregate": agg}
    (out_dir / "summary.json").write_text(json.dumps(_nan_to_none(summary), indent=1))
    _plots(out_dir, agg, records, tasks, methods, label, preset)
    return out_dir / "report.md"


def _given_table(methods: list[str], label: dict, preset: dict, agg: dict) -> list[str]:
    """One row per method: what it was given (the training arguments the grid passed) and its measured NFE."""
    rows = ["## What each method was given", "",
            f"Every method: batch {preset['batch_size']}, the same demos and evaluations; {preset['steps']} steps "
            "unless the preset gives a method its own budget (method_steps). NFE: network evaluations per chunk, "
            "measured on the final checkpoints.", "",
            "| Method | lr | schedule | steps | acts with | chunk (predicted / executed) | inputs | NFE per chunk |",
            "|---|---|---|---|---|---|---|---|"]
    for m in methods:
        if m not in METHODS:
            continue
        g = given(m, preset)
        nfe = mean_std([agg[m][t]["nfe"][0] for t in agg[m]])[0]
        rows.append(f"| {label[m]} | {g['lr']} | {g['schedule']} | {g['steps']} | {g['acts']} | {g['chunk']} | "
                    f"{g['inputs']} | {nfe:.0f} |")
    return rows + [""]


#: Analyses of a finished grid's runs written beside its report: (file pattern, tool module, what it asks).
DIAGNOSTICS: tuple[tuple[str, str, str], ...] = (
    ("expert_gap.md", "expert-gap", "Where do the runs fail? Each final checkpoint against MetaWorld's scripted "
                                    "expert, state by state, success inside / outside the demos' placements, and "
                                    "where the actions jitter (at re-plans or inside chunks)."),
    ("tau_profile.md", "tau-profile", "Where along the flow is each focal-family checkpoint's one-step map still "
                                      "wrong, on its demos and on held-out episodes?"),
    ("variant_*.md", "variant-eval", "Would the final checkpoints act better with another inference setting, on "
                                     "the same fresh episodes?"),
    ("checkpoint_eval.md", "checkpoint-eval", "Do a run's late checkpoints act differently, or do only the draws of "
                                              "its periodic evaluations swing? Each on the same fresh episodes."),
)


def _diagnostics(out_dir: Path) -> list[str]:
    """One line per diagnostic tool whose output is in ``out_dir``, linking its files; no section if none."""
    rows = []
    for pattern, tool, question in DIAGNOSTICS:
        links = ", ".join(f"[{path.stem}]({path.name})" for path in sorted(out_dir.glob(pattern)))
        if links:
            rows.append(f"- {links} (`lerobot-focal-bench {tool}`): {question}")
    return ["## Diagnostics of the finished runs", "", *rows, ""] if rows else []


def _nan_to_none(x):
    """JSON has no NaN: a missing number (no fresh episodes, one seed's std) is written as null."""
    if isinstance(x, float):
        return None if math.isnan(x) else x
    if isinstance(x, dict):
        return {k: _nan_to_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_nan_to_none(v) for v in x]
    return x


def _plots(out_dir: Path, agg: dict, records: list[RunRecord], tasks: list[str], methods: list[str], label: dict,
           preset: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(len(tasks), 3)
    rows = -(-len(tasks) // cols)
    for name, key, ylabel in (("learning_curves", "curve", "success (mean over seeds)"),
                              ("compounding_error", "compounding", "compounding error (open loop)")):
        fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
        for ax, task in zip(axes.flat, tasks, strict=False):  # the grid may have more cells than tasks
            for i, m in enumerate(methods):
                if task not in agg[m]:
                    continue
                e = agg[m][task]
                if key == "curve":
                    x, y, s = np.array(e["curve_steps"]), np.array(e["curve_success"]), np.array(e["curve_success_std"])
                    ax.plot(x, y, marker=".", color=f"C{i}", label=label[m])
                    ax.fill_between(x, y - s, y + s, color=f"C{i}", alpha=0.15)
                    if m == "focal" and task in PAPER_FOCAL_TOP5:
                        ax.axhline(PAPER_FOCAL_TOP5[task] / 100, color=f"C{i}", ls="--", lw=0.8,
                                   label="FocalPolicy, paper (top-5)")
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
        save_png(fig, out_dir / f"{name}.png", dpi=100)

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
    save_png(fig, out_dir / "success_bars.png", dpi=100)
    _plot_learning_efficiency(out_dir, records, tasks, methods, label, preset)


#: Update times of one method's runs further apart than this: the machine's speed changed between them.
SPEED_SPREAD = 1.5


#: Costs of the network alone: every task feeds it the same input shapes, so each run measures one number once.
NETWORK_COSTS = ("latency_ms", "update_s_per_step", "nfe")


def cost_per_run(records: list[RunRecord], method: str, key: str) -> float:
    """`method`'s cost per run; nan without any finished run. Cost needs no whole seed. A cost of the network alone
    (NETWORK_COSTS) is the median over runs: each run timed the same network once, on a shared machine whose speed
    changes between sessions, and the median is what one run timed while the machine was slow cannot move. Wall
    time depends on the task (episode lengths), so it is the mean over tasks of each task's mean, which keeps a
    method whose extra seeds ran on slow tasks from looking slower. The Cost table and the latency goal both
    read this."""
    runs = [r for r in records if r.method == method and getattr(r, key) is not None]
    if key in NETWORK_COSTS:
        return float(np.median([r.value(key) for r in runs])) if runs else math.nan
    by_task: dict[str, list[float]] = defaultdict(list)
    for r in runs:
        by_task[r.task].append(r.value(key))
    return mean_std([float(np.mean(v)) for v in by_task.values()])[0]


def _update_range(records: list[RunRecord], method: str) -> tuple[float, float]:
    """The fastest and slowest mean update time (s/step) of `method`'s runs; (nan, nan) without any."""
    times = [r.update_s_per_step for r in records if r.method == method and r.update_s_per_step]
    return (min(times), max(times)) if times else (math.nan, math.nan)


def learning_efficiency(records: list[RunRecord], tasks: list[str], method: str, batch_size: int) -> dict | None:
    """The method's success at each evaluation, averaged over the tasks and seeds it has every task of, against
    the training samples seen (step × batch) and the wall-clock minutes spent (each run's wall time, training
    and periodic evaluations, prorated by step: the runs log no time per evaluation). None without a whole seed.

    This is the paper's learning-efficiency comparison: how much data and how much time a method needs to
    reach a success rate, beside what it reaches."""
    by_seed: dict[int, dict[str, RunRecord]] = defaultdict(dict)
    for r in records:
        if r.method == method and r.task in tasks and r.curve:
            by_seed[r.seed][r.task] = r
    runs = [r for seed_runs in by_seed.values() if len(seed_runs) == len(tasks) for r in seed_runs.values()]
    if not runs:
        return None
    n = min(len(r.curve) for r in runs)
    steps = np.array([c["step"] for c in runs[0].curve[:n]], dtype=float)
    success = np.mean([[c["success"] for c in r.curve[:n]] for r in runs], axis=0)
    minutes = np.mean([[c["step"] / r.curve[-1]["step"] * (r.wall_s or math.nan) / 60 for c in r.curve[:n]]
                       for r in runs], axis=0)
    return {"samples": (steps * batch_size).tolist(), "minutes": minutes.tolist(), "success": success.tolist(),
            "runs": len(runs)}


def _learning_efficiency_section(records: list[RunRecord], tasks: list[str], methods: list[str], label: dict,
                                 preset: dict) -> list[str]:
    rows, partial = [], []
    for m in methods:
        e = learning_efficiency(records, tasks, m, preset["batch_size"])
        if e is None:
            if any(r.method == m and r.task in tasks and r.curve for r in records):
                partial.append(label[m])
            continue
        best = max(e["success"])
        # The first evaluation at 90 % of the method's own best mean success: how soon it gets most of the way.
        i = next(k for k, v in enumerate(e["success"]) if v >= 0.9 * best)
        rows.append(f"| {label[m]} | {e['runs']} | {best * 100:.1f} | {e['samples'][i] / 1e3:.0f} k | "
                    f"{e['minutes'][i]:.1f} |")
    if not rows:
        return []
    return ["## Learning efficiency", "",
            "Success at each periodic evaluation, averaged over the tasks and over the seeds that have every task, "
            "against training samples (step × batch) and against wall-clock minutes (each run's wall time prorated by "
            "step; runs shared the machine, so compare methods of one grid only). The table: the best of that mean "
            "curve and the samples and minutes of the first evaluation at 90 % of it.", "",
            "| Method | runs | best mean success (%) | samples to 90 % of it | minutes to 90 % of it |",
            "|---|---|---|---|---|", *rows, "",
            *([f"Left out, no seed has every task yet: {', '.join(partial)} (see its cells above).", ""]
              if partial else []),
            "![learning efficiency](learning_efficiency.png)", ""]


def _plot_learning_efficiency(out_dir: Path, records: list[RunRecord], tasks: list[str], methods: list[str],
                              label: dict, preset: dict) -> None:
    import matplotlib.pyplot as plt

    curves = {m: e for m in methods if (e := learning_efficiency(records, tasks, m, preset["batch_size"]))}
    if not curves:
        return
    fig, (by_samples, by_time) = plt.subplots(1, 2, figsize=(10, 3.6))
    for i, m in enumerate(methods):
        if m in curves:
            e = curves[m]
            by_samples.plot(np.array(e["samples"]) / 1e3, np.array(e["success"]) * 100, marker=".", color=f"C{i}",
                            label=label[m])
            by_time.plot(e["minutes"], np.array(e["success"]) * 100, marker=".", color=f"C{i}", label=label[m])
    by_samples.set_xlabel("training samples (thousands)")
    by_time.set_xlabel("wall-clock minutes per run")
    for ax in (by_samples, by_time):
        ax.set_ylabel("success, mean over tasks (%)")
        ax.set_ylim(-5, 105)
        ax.grid(alpha=0.3)
    by_samples.legend(fontsize=7)
    fig.suptitle(f"preset {preset['name']}: learning efficiency ({', '.join(tasks)})", fontsize=9)
    save_png(fig, out_dir / "learning_efficiency.png", dpi=100)


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="lerobot-focal-bench report", description=__doc__)
    parser.add_argument("--out", type=Path, required=True, help="the grid's --out directory")
    args = parser.parse_args(argv)
    print(write_report(args.out).read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
