"""`lerobot-focal-bench grid`: run (task × method × seed) through `lerobot-train`, resumably, then report.

    lerobot-focal-bench grid --preset cpu --tasks pick-place,sweep-into,disassemble,push-wall,basketball \\
        --methods core --out docs/benchmarks/grid_cpu --jobs 2
    lerobot-focal-bench grid --preset paper --tasks medium --methods all --executor ray --ray-address auto \\
        --gpus-per-run 1 --cpus-per-run 8 --work /shared/bench --out results/grid_paper

``--out`` holds ``results.jsonl`` (one line per finished run, the resume point), ``report.md`` and the plots;
``--work`` holds datasets, checkpoints and logs. Rerunning the same command skips every run that has an ``ok``
line and retries failed ones; ``lerobot-focal-bench report --out DIR`` re-renders the report alone.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from dataclasses import replace
from pathlib import Path

from ...console import doc_parser
from ...datasets.making.collect import table_clearance_arg
from .grid_presets import DEMO_SEED, PERIODIC_EVALS, PRESETS, SCHEDULES
from .methods import resolve_method_phases
from .metrics import eval_curve
from .results import ResultsFile, RunRecord
from .resume import seeded_episodes
from .run import resumable_step
from .seeds import RESCORE_BLOCKS, check_seed_ranges
from .specs import RunSpec, make_specs

DEV_TASKS = "pick-place,sweep-into,disassemble,push-wall,basketball"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = doc_parser(__doc__, "lerobot-focal-bench grid")
    p.add_argument("--preset", choices=sorted(PRESETS), default="cpu")
    p.add_argument("--tasks", default=DEV_TASKS,
                   help="MetaWorld v3 tasks and/or groups (easy, medium, hard, very_hard); "
                        "default: the development set")
    p.add_argument("--methods", default="core",
                   help="comma-separated methods, 'core', 'all' or 'plateau'; '|' separates phases: every run of a "
                        "phase comes before the next phase's (default: core)")
    p.add_argument("--seeds", default=None, help="comma-separated training seeds (default: the preset's)")
    p.add_argument("--out", type=Path, required=True, help="results.jsonl, report.md and plots go here")
    p.add_argument("--work", type=Path, default=None, help="datasets, checkpoints, logs (default: outputs/bench)")
    p.add_argument("--executor", choices=["local", "ray"], default="local")
    p.add_argument("--jobs", type=int, default=1, help="local executor: runs at a time (default 1)")
    p.add_argument("--ray-address", default=None,
                   help="Ray: 'auto' or an address to join a cluster; default: start a local Ray instance")
    p.add_argument("--cpus-per-run", type=float, default=1.0)
    p.add_argument("--gpus-per-run", type=float, default=0.0)
    p.add_argument("--retries", type=int, default=1, help="extra attempts for a failed run (default 1)")
    p.add_argument("--dry-run", action="store_true", help="list the runs still to do and exit")
    for name in ("steps", "batch_size", "eval_every", "eval_episodes", "demos", "heldout_demos", "episode_length",
                 "final_episodes", "train_points", "eval_points"):
        p.add_argument(f"--{name.replace('_', '-')}", dest=name, type=int, default=None,
                       help=f"override the preset's {name}")
    p.add_argument("--lr", type=float, default=None,
                   help="learning rate of every method (replaces the preset's lr and its per-method rates, method_lr)")
    p.add_argument("--demo-seed", dest="demo_seed", type=int, default=None,
                   help=f"first reset seed of the training demos (default {DEMO_SEED}): another set of placements")
    p.add_argument("--periodic-eval", dest="periodic_eval", choices=PERIODIC_EVALS, default=None,
                   help="override the preset's periodic evaluations: 'fixed' (the same placements every time, "
                        "LeRobot's default) or 'fresh' (new ones at every evaluation and seed, as DP3's runner)")
    p.add_argument("--demos-per-seed", dest="demos_per_seed", default=None, type=_bool,
                   help="override the preset's demos_per_seed (true: every training seed its own demos)")
    p.add_argument("--schedule", default=None, choices=sorted(SCHEDULES),
                   help="override the preset's learning-rate schedule after the warm-up: 'cosine' (to zero at the "
                        "last step) or 'constant' (how the plateau budget is measured); ACT's rate is always constant")
    p.add_argument("--table-clearance", dest="table_clearance", default=NOT_GIVEN, type=table_clearance_arg,
                   help="point clouds: crop the table top this far above its surface (m), or 'none' to keep the "
                        "table (default: the preset's, the env's 0.005)")
    p.add_argument("--device", default=None, help="override the preset's device (cpu, cuda)")
    p.add_argument("--down-dims", default=None, type=_int_tuple,
                   help="override the preset's U-Net widths, e.g. 64,128,256 (every method)")
    p.add_argument("--keep-checkpoints-from", dest="keep_checkpoints_from", type=int, default=None, metavar="STEP",
                   help="keep every step checkpoint from STEP on, not only the last (for `lerobot-focal-bench "
                        "checkpoint-eval`; changes no result, so it is not recorded in grid.json). Give it when a "
                        "run starts: a run resumed with it has already dropped its earlier checkpoints")
    return p.parse_args(argv)


#: --table-clearance not given (None is a value of it: keep the table).
NOT_GIVEN = object()


def _bool(text: str) -> bool:
    if text.lower() not in ("true", "false"):
        raise argparse.ArgumentTypeError(f"expected true or false; got {text!r}")
    return text.lower() == "true"


def _int_tuple(text: str) -> tuple[int, ...]:
    try:
        dims = tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        dims = ()
    if not dims or min(dims) < 1:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers such as 64,128,256; got {text!r}")
    return dims


def build_specs(args: argparse.Namespace) -> tuple[list[RunSpec], dict]:
    from lerobot_focal.envs.focal_metaworld import resolve_metaworld_tasks

    overrides = {k: v for k, v in dict(
        steps=args.steps, batch_size=args.batch_size, eval_every=args.eval_every, eval_episodes=args.eval_episodes,
        demos=args.demos, heldout_demos=args.heldout_demos, episode_length=args.episode_length, device=args.device,
        final_episodes=args.final_episodes, down_dims=args.down_dims, lr=args.lr, demo_seed=args.demo_seed,
        periodic_eval=args.periodic_eval, demos_per_seed=args.demos_per_seed, schedule=args.schedule,
        train_points=args.train_points, eval_points=args.eval_points,
    ).items() if v is not None}
    preset = PRESETS[args.preset].with_overrides(**overrides)
    if args.table_clearance is not NOT_GIVEN:  # None keeps the table, which with_overrides would read as unset
        clearance = overrides["table_clearance"] = args.table_clearance
        preset = (preset.with_none("table_clearance") if clearance is None
                  else preset.with_overrides(table_clearance=clearance))
    if preset.steps % preset.eval_every:
        raise SystemExit(f"--steps ({preset.steps}) must be a multiple of --eval-every ({preset.eval_every})")
    tasks = list(dict.fromkeys(t.removesuffix("-v3") for g in resolve_metaworld_tasks(args.tasks).values()
                               for t in g))
    phases = resolve_method_phases(args.methods)
    methods = [m for phase in phases for m in phase]
    seeds = [int(s) for s in args.seeds.split(",")] if args.seeds else list(preset.seeds)
    # Demos, held-out demos, periodic and final evaluations, expert_gap and re-score never share a reset seed.
    check_seed_ranges(preset, seeds, rescore_episodes=RESCORE_BLOCKS * preset.eval_episodes)
    work = (args.work or Path("outputs/bench")).resolve()
    specs = make_specs(preset, tasks, [[m.name for m in p] for p in phases], seeds, work)
    if args.keep_checkpoints_from is not None:
        last = max(s.preset.steps for s in specs)
        if not 0 < args.keep_checkpoints_from < last:
            raise SystemExit(f"--keep-checkpoints-from {args.keep_checkpoints_from}: give a step between 1 and the "
                             f"last step, {last} (that one is always kept)")
        specs = [replace(s, keep_checkpoints_from=args.keep_checkpoints_from) for s in specs]
    return specs, {"preset": preset.to_dict(), "overrides": overrides, "tasks": tasks,
                   "methods": [m.name for m in methods], "phases": [[m.name for m in p] for p in phases],
                   "seeds": seeds}


#: Preset fields that do not change what a run measures, left out when two invocations' presets are compared.
_DESCRIPTIVE_PRESET_FIELDS = ("notes",)
#: Preset fields an override makes irrelevant: with --lr every method trains at it, whatever method_lr says (so
#: a sweep resumes after a chosen rate is recorded in the preset); with --steps every method trains that long.
_SUPERSEDED = {"lr": ("method_lr",), "steps": ("method_steps",)}
#: Preset fields of (method, value) pairs: an invocation may change a method's entry while the folder holds no
#: finished run of that method (a budget or rate chosen after the grid began, before that method's first run).
_PER_METHOD_FIELDS = ("method_lr", "method_steps")


def _methods_run(out: Path) -> set[str]:
    """The methods with a finished run in ``out``."""
    return {record.method for record in ResultsFile(out / "results.jsonl").ok().values()}


def _per_method_change_is_free(old: list, new: list, run: set[str]) -> bool:
    """Whether two (method, value) lists differ only for methods without a finished run."""
    old_of, new_of = dict(map(tuple, old)), dict(map(tuple, new))
    return all(old_of.get(m) == new_of.get(m) for m in (old_of.keys() | new_of.keys()) & run)


def merged_grid(previous: dict | None, grid: dict, out: Path) -> dict:
    """The grid that ``out/grid.json`` records once this invocation has run: the union of every invocation's.

    Runs are keyed by task, method and seed only, so a results directory grows one invocation at a time (another
    method, another seed) and its report covers them all. Invocations with another preset or other overrides
    would mix runs that measure different things under one key, so they are refused; nothing is written then.
    A method's own rate or budget (``_PER_METHOD_FIELDS``) may change while the folder holds none of its runs.
    """
    if previous is None:
        return grid

    def canonical(value):  # tuples and lists alike, as grid.json stores them
        return json.loads(json.dumps(value, default=str))

    old_preset, new_preset = canonical(previous.get("preset", {})), canonical(grid["preset"])
    old_over, new_over = canonical(previous.get("overrides", {})), canonical(grid["overrides"])
    differing = [(f"--{k.replace('_', '-')}", old_over.get(k), new_over.get(k))
                 for k in sorted(old_over.keys() | new_over.keys()) if old_over.get(k) != new_over.get(k)]
    overridden = set(old_over) | set(new_over)
    superseded = {field for over in overridden & set(_SUPERSEDED) for field in _SUPERSEDED[over]}
    changed = [k for k in sorted(old_preset.keys() & new_preset.keys())
               if k not in {*_DESCRIPTIVE_PRESET_FIELDS, "overridden", *overridden, *superseded}
               and old_preset[k] != new_preset[k]]
    run = _methods_run(out) if set(changed) & set(_PER_METHOD_FIELDS) else set()
    differing += [(f"preset {k}", old_preset[k], new_preset[k]) for k in changed
                  if not (k in _PER_METHOD_FIELDS and _per_method_change_is_free(old_preset[k], new_preset[k], run))]
    if differing:
        shown = "; ".join(f"{name}: {old!r} there, {new!r} now" for name, old, new in differing)
        raise SystemExit(
            f"{out} holds a grid run with other settings ({shown}). Its runs are keyed by task, method and seed "
            f"only, so new runs would be mixed with those. Use another --out, or the preset and overrides that "
            f"{out / 'grid.json'} records.")

    def union(a: list, b: list) -> list:
        return list(a) + [x for x in b if x not in a]

    methods = union(previous["methods"], grid["methods"])
    old_phases = previous.get("phases", [previous["methods"]])
    new_phases = [[m for m in phase if m not in previous["methods"]] for phase in grid["phases"]]
    return {**grid, "tasks": union(previous["tasks"], grid["tasks"]), "methods": methods,
            "phases": [p for p in old_phases + new_phases if p], "seeds": union(previous["seeds"], grid["seeds"])}


def _stop_on_signals() -> None:
    """SIGTERM (a scheduler, `kill`) stops the grid like Ctrl-C: runs in flight are stopped, finished ones kept.
    SIGINT gets Python's handler back even when the driver was started in the background (where shells ignore
    it), so `kill -INT` works too."""
    import signal

    def _interrupt(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, signal.default_int_handler)


def _progress(spec: RunSpec, step: int) -> str:
    """Where an unfinished run stands: its resume step and the success of each evaluation so far (a run another
    grid process is training shows its progress too)."""
    seeded, n = seeded_episodes(spec.run_dir), spec.preset.eval_episodes
    curve = eval_curve(seeded[: len(seeded) // n * n], n, spec.preset.eval_every)  # an evaluation under way: left out
    shown = ", ".join(f"{e['step']}: {100 * e['success']:.0f} %" for e in curve)
    return f" (continues from step {step} of {spec.preset.steps}; success at each evaluation so far: {shown})"


def main(argv: list[str] | None = None) -> int:
    # force: an import on the way (LeRobot's) has already set up the root logger at WARNING, which hid these lines
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", force=True)
    _stop_on_signals()
    args = parse_args(argv)
    specs, grid = build_specs(args)
    grid_file = args.out / "grid.json"
    recorded = merged_grid(json.loads(grid_file.read_text()) if grid_file.exists() else None, grid, args.out)
    results = ResultsFile(args.out / "results.jsonl")
    done = results.ok()
    todo = [s for s in specs if s.key not in done]
    capped = [f"{m} on {n}" for m, n in grid["preset"]["seed_caps"] if m in grid["methods"]]
    print(f"[grid] {len(specs)} runs ({len(grid['tasks'])} tasks x {len(grid['methods'])} methods x "
          f"{len(grid['seeds'])} seeds" + (f"; {', '.join(capped)}" if capped else "") + "), "
          f"{len(specs) - len(todo)} already in {results.path}, {len(todo)} to do")
    print(f"[grid] preset {grid['preset']['name']}: {grid['preset']['notes']}")
    if grid["overrides"]:
        print("[grid] overridden on the command line: " + ", ".join(f"{k}={v}" for k, v in grid["overrides"].items()))
    resumable = {s.key: step for s in todo if (step := resumable_step(s)) is not None}
    if resumable:
        print(f"[grid] {len(resumable)} of them continue from a checkpoint: "
              + ", ".join(f"{k} at step {v}" for k, v in resumable.items()))
    if args.dry_run:
        for s in todo:
            print("  ", s.key + (_progress(s, resumable[s.key]) if s.key in resumable else ""))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)  # not before: a dry run leaves no empty results folder behind
    grid_file.write_text(json.dumps(recorded, indent=2, default=str))

    from tqdm import tqdm

    bar = tqdm(total=len(specs), initial=len(specs) - len(todo), unit="run", file=sys.stdout)
    failed: list[str] = []
    t0 = time.perf_counter()

    def on_result(record: RunRecord) -> None:
        results.append(record)
        bar.update(1)
        if record.status == "ok":
            fresh = record.success_fresh
            fresh_text = f", final checkpoint on fresh episodes {fresh:.2f}" if fresh is not None else ""
            bar.write(f"[grid] {record.key}: top-{todo[0].preset.top_k} success {record.success_top_k:.2f}, "
                      f"last evaluation {record.success_final:.2f}{fresh_text}, ATV {record.atv:.4f}, "
                      f"{record.wall_s / 60:.1f} min")
        else:
            failed.append(record.key)
            bar.write(f"[grid] {record.key}: FAILED after {record.attempts} attempts: "
                      f"{(record.error or '').splitlines()[0]}")

    try:
        if args.executor == "ray":
            from .executors import run_ray

            run_ray(todo, on_result, args.retries, args.ray_address, args.cpus_per_run, args.gpus_per_run)
        else:
            from .executors import run_local

            run_local(todo, on_result, args.retries, args.jobs)
    except KeyboardInterrupt:
        bar.close()
        print(f"\n[grid] interrupted: finished runs are in {results.path}; rerun the same command to resume")
        return 130
    bar.close()
    print(f"[grid] {len(todo)} runs in {(time.perf_counter() - t0) / 60:.1f} min; {len(failed)} failed"
          + (f": {', '.join(failed)}" if failed else ""))

    from .report import write_report

    write_report(args.out)
    return 1 if failed else 0



if __name__ == "__main__":
    raise SystemExit(main())
