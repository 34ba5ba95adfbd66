"""Do a run's late checkpoints differ, or only the draws of placements they were evaluated on?

    lerobot-focal-bench grid --preset cpu_fair --tasks disassemble --methods focal --seeds 0 \\
        --keep-checkpoints-from 15000 --out DIR --work WORK
    lerobot-focal-bench checkpoint-eval --out DIR --work WORK [--methods focal] [--tasks ...] [--seeds ...]

Why: with the paper's estimator every periodic evaluation draws 20 new placements, so a curve that swings late in
training (focal on disassemble: 90, 70, 50, 70, 35 % over its last five evaluations while the rate went to zero)
mixes two things: checkpoints that act differently, and the luck of each draw (one evaluation of 20 episodes at
65 % has a standard deviation of 11 points). Which one it is decides the fix: swinging checkpoints are a method
question (weight averaging, an earlier stop), swinging draws are only the estimator's noise.

How: every step checkpoint the run kept (``grid --keep-checkpoints-from``) is evaluated on the very episodes of
the grid's final evaluation (same reset seeds, same policy-noise seed), and the final checkpoint's own episodes
are read back from the grid's run. Each episode is then one placement seen by every checkpoint, and Cochran's Q
tests whether the checkpoints' success rates on those placements differ by more than chance.

Writes ``checkpoint_eval.json`` (per run: steps, the periodic evaluation at each step, success on the shared
episodes, each episode's outcome, the test), ``checkpoint_eval.md`` and ``checkpoint_eval.png`` beside the
grid's report, and re-renders the report (which links them); resumable (checkpoints already evaluated are
kept). Run it between grid invocations, not beside a running grid.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ....console import doc_parser
from ..processes import run_logged
from ..resume import checkpoints, seeded_records
from ..revisit import add_run_filters, finished_runs, no_runs_message
from ..run import child_env, final_eval_command
from ..specs import RunSpec, specs_of_grid

TOOL = "checkpoint_eval"


def read_episodes(path: Path) -> dict[int, float]:
    """Success by reset seed of an evaluation's episode file."""
    return {int(e["seed"]): float(e["success"]) for e in seeded_records(path)}


#: Random row-wise permutations behind Cochran's Q's p-value (seeded: the same outcomes give the same p).
PERMUTATIONS = 20_000


def cochran_q(outcomes: np.ndarray, permutations: int = PERMUTATIONS) -> dict:
    """Cochran's Q for k related binary samples: rows are episodes (placements), columns checkpoints.

    Under H0 every checkpoint succeeds with the same probability on each placement, so within a row the outcomes
    are exchangeable. ``p`` is that permutation test's (each row's outcomes shuffled among the checkpoints; exact
    in the limit), because with 50 episodes only a handful may tell the checkpoints apart, where the χ²(k − 1)
    approximation (``p_chi2``, beside it) is too small. Episodes every checkpoint solved, or none did, carry no
    information and drop out of the statistic."""
    from scipy import stats

    x = np.asarray(outcomes, dtype=np.float64)
    n, k = x.shape
    if k < 2 or n == 0:
        raise ValueError(f"Cochran's Q needs ≥ 2 checkpoints and ≥ 1 episode, got {k} and {n}")
    row = x.sum(axis=1)
    informative = x[(row > 0) & (row < k)]
    if len(informative) == 0:  # every episode all-or-nothing across checkpoints: no evidence of any difference
        return {"q": 0.0, "df": k - 1, "p": 1.0, "p_chi2": 1.0, "informative_episodes": 0}

    def q_of(y: np.ndarray) -> np.ndarray:  # y: (..., rows, k); rows' totals are fixed under the permutations
        col, r = y.sum(axis=-2), y.sum(axis=-1)
        total = r.sum(axis=-1)
        return (k - 1) * (k * (col ** 2).sum(axis=-1) - total ** 2) / (k * total - (r ** 2).sum(axis=-1))

    q = float(q_of(informative))
    rng = np.random.default_rng(0)
    shuffled = rng.permuted(np.broadcast_to(informative, (permutations, *informative.shape)), axis=-1)
    p_perm = (1 + int((q_of(shuffled) >= q - 1e-9).sum())) / (permutations + 1)
    return {"q": q, "df": k - 1, "p": float(p_perm), "p_chi2": float(stats.chi2.sf(q, k - 1)),
            "informative_episodes": len(informative)}


def evaluate_checkpoint(spec: RunSpec, step: int, checkpoint: Path) -> dict[int, float]:
    """The checkpoint on the grid's final-evaluation episodes; its own episode file and log in the run folder."""
    name = f"ckpt{step}"
    path = spec.run_dir / f"{name}_episodes.jsonl"
    path.unlink(missing_ok=True)  # of an interrupted evaluation
    run_logged(final_eval_command(spec, checkpoint / "pretrained_model", name=name), spec.run_dir / f"{name}_eval.log",
               child_env(spec.preset), f"lerobot-eval (checkpoint {step})")
    return read_episodes(path)


def _cached(entry: dict | None, finished_at: str | None, seeds: list[int]) -> dict[int, dict[int, float]]:
    """Earlier evaluations of this very run (the same training, by its record's ``finished_at``) on the final
    evaluation's seeds; anything else is dropped and evaluated again."""
    if not entry or entry.get("run_finished_at") != finished_at:
        return {}
    by_step = {int(k): {int(s): v for s, v in eps.items()} for k, eps in entry.get("episodes", {}).items()}
    return {step: eps for step, eps in by_step.items() if sorted(eps) == seeds}


def measure_run(spec: RunSpec, record, entry: dict | None, save) -> dict:
    """Evaluate the run's kept checkpoints not yet in ``entry``; the final one is the grid's own evaluation.

    ``save(partial)`` is called after each checkpoint, so an interrupted pass keeps what it evaluated."""
    final_path = spec.run_dir / "final_episodes.jsonl"
    if not final_path.exists():
        raise FileNotFoundError(f"{final_path} is missing: the grid's final evaluation of {spec.key} is gone (its "
                                "work folder was cleaned?); checkpoint-eval compares against those very episodes")
    final = read_episodes(final_path)
    by_step = _cached(entry, record.finished_at, sorted(final))
    by_step[spec.preset.steps] = final
    kept = {s: p for s, p in checkpoints(spec.run_dir).items() if s < spec.preset.steps}
    if not kept and len(by_step) < 2:
        raise FileNotFoundError(
            f"{spec.key} kept no step checkpoint before its last: delete its line from results.jsonl and its run "
            f"folder {spec.run_dir}, then train it again with `lerobot-focal-bench grid ... --keep-checkpoints-from "
            "STEP` to compare late checkpoints")
    periodic = {c["step"]: c["success"] for c in record.curve}
    for step, path in sorted(kept.items()):
        if step not in by_step:
            by_step[step] = evaluate_checkpoint(spec, step, path)
            print(f"[checkpoint-eval] {spec.key} step {step}: {100 * np.mean(list(by_step[step].values())):.0f} % "
                  f"on {len(by_step[step])} episodes", flush=True)
            save({"run_finished_at": record.finished_at, "episodes": _episodes_json(by_step)})
    return {"run_finished_at": record.finished_at,
            **summarize(by_step, periodic, spec.preset.eval_episodes)}


def _episodes_json(by_step: dict[int, dict[int, float]]) -> dict:
    return {str(s): {str(seed): v for seed, v in eps.items()} for s, eps in sorted(by_step.items())}


def summarize(by_step: dict[int, dict[int, float]], periodic: dict[int, float], periodic_episodes: int) -> dict:
    """The per-run entry: success per checkpoint on the shared episodes, the periodic number at the same steps,
    Cochran's Q across checkpoints, and the spread the draw of a periodic evaluation alone would give."""
    steps = sorted(by_step)
    seeds = sorted(by_step[steps[-1]])
    for step in steps:
        if sorted(by_step[step]) != seeds:
            raise ValueError(f"checkpoint {step} was evaluated on other seeds than the final checkpoint: the "
                             "comparison needs the same episodes for every checkpoint")
    outcomes = np.array([[by_step[s][seed] for s in steps] for seed in seeds])
    shared = outcomes.mean(axis=0)
    p = float(shared.mean())
    return {
        "steps": steps,
        "shared_success": [float(x) for x in shared],
        "periodic_success": [periodic.get(s) for s in steps],
        "shared_episodes": len(seeds),
        "periodic_episodes": periodic_episodes,
        # What an evaluation's draw of placements alone spreads a success rate by, at the checkpoints' mean rate.
        "binomial_sd_shared": (p * (1 - p) / len(seeds)) ** 0.5,
        "binomial_sd_periodic": (p * (1 - p) / periodic_episodes) ** 0.5,
        "cochran": cochran_q(outcomes) if len(steps) > 1 else None,
        "episodes": _episodes_json({s: by_step[s] for s in steps}),
    }


def render(done: dict[str, dict]) -> str:
    md = ["# Late checkpoints on the same episodes", "",
          "`lerobot-focal-bench checkpoint-eval --out <grid>`: each kept checkpoint of a run on the episodes of the "
          "grid's final evaluation (same placements, same policy noise), beside the run's periodic evaluation at "
          "that step (its own fresh draw of placements). Cochran's Q: do the checkpoints differ on the shared "
          "placements by more than chance?", ""]
    for key in sorted(k for k in done if "steps" in done[k]):  # not runs whose pass was interrupted
        e = done[key]
        periodic = [x for x in e["periodic_success"] if x is not None]
        md += [f"## {key.replace('|', ' · ')}", "",
               "| step | " + " | ".join(str(s) for s in e["steps"])
               + " | sd across checkpoints | sd of the draw alone |",
               "|---|" + "---|" * (len(e["steps"]) + 2),
               f"| periodic evaluation ({e['periodic_episodes']} own episodes), % | "
               + " | ".join("–" if x is None else f"{100 * x:.0f}" for x in e["periodic_success"])
               + f" | {100 * float(np.std(periodic, ddof=1)) if len(periodic) > 1 else float('nan'):.1f} "
               f"| {100 * e['binomial_sd_periodic']:.1f} |",
               f"| same {e['shared_episodes']} episodes, % | "
               + " | ".join(f"{100 * x:.0f}" for x in e["shared_success"])
               + f" | {100 * float(np.std(e['shared_success'], ddof=1)):.1f} | {100 * e['binomial_sd_shared']:.1f} |",
               ""]
        c = e.get("cochran")
        if c:
            verdict = ("the checkpoints act differently on the same placements" if c["p"] < 0.05 else
                       f"no evidence on these {e['shared_episodes']} episodes that the checkpoints differ (a "
                       "difference smaller than these episodes resolve is not ruled out)")
            md += [f"Cochran's Q = {c['q']:.2f} on {c['df']} degrees of freedom, p = {c['p']:.3f} (permutation "
                   f"test; χ² approximation {c.get('p_chi2', c['p']):.3f}); {c['informative_episodes']} of "
                   f"{e['shared_episodes']} episodes told the checkpoints apart: {verdict}.", ""]
    return "\n".join(md)


def plot(done: dict[str, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ....figures import save_png

    keys = sorted(k for k in done if "steps" in done[k])
    fig, axes = plt.subplots(1, len(keys), figsize=(5 * len(keys), 3.6), squeeze=False)
    for ax, key in zip(axes[0], keys, strict=True):
        e = done[key]
        steps = e["steps"]
        periodic = [(s, 100 * x) for s, x in zip(steps, e["periodic_success"], strict=True) if x is not None]
        if periodic:
            ax.plot([s for s, _ in periodic], [x for _, x in periodic], "o--", color="tab:gray",
                    label=f"periodic ({e['periodic_episodes']} own episodes)")
        shared = [100 * x for x in e["shared_success"]]
        sd = 100 * e["binomial_sd_shared"]
        ax.errorbar(steps, shared, yerr=sd, fmt="o-", color="tab:blue", capsize=3,
                    label=f"same {e['shared_episodes']} episodes (± draw sd)")
        ax.set_title(key.replace("|", " · "), fontsize=9)
        ax.set_xlabel("training step")
        ax.set_ylim(-5, 105)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("success, %")
    axes[0][0].legend(fontsize=7, loc="lower left")
    save_png(fig, path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench checkpoint-eval")
    add_run_filters(p, "focal", "methods whose runs kept checkpoints")
    args = p.parse_args(argv)
    done_path = args.out / f"{TOOL}.json"
    done = json.loads(done_path.read_text()) if done_path.exists() else {}
    records = finished_runs(args, need=("success_fresh",))
    if not records and not done:
        no_runs_message("checkpoint-eval", args, json.loads((args.out / "grid.json").read_text())["methods"])
        return 2
    specs = specs_of_grid(args.out, args.work)
    failed = []

    def save(key: str, entry: dict) -> None:
        done[key] = entry
        done_path.write_text(json.dumps(done, indent=1))

    for r in records:
        spec = specs.get(r.key)
        if spec is None:
            continue
        try:
            save(r.key, measure_run(spec, r, done.get(r.key), lambda partial, key=r.key: save(key, partial)))
        except FileNotFoundError as err:
            if "steps" not in done.get(r.key, {}):
                failed.append(str(err))
    for message in failed:
        print(f"[checkpoint-eval] skipped: {message}")
    if not any("steps" in e for e in done.values()):
        return 2
    (args.out / f"{TOOL}.md").write_text(render(done))
    plot(done, args.out / f"{TOOL}.png")
    print(render(done))
    from ..report import write_report

    print(f"[checkpoint-eval] report with a link to {TOOL}.md: {write_report(args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
