"""Shared command line of the tools that revisit a finished grid's runs (expert_gap, variant_eval, tau_profile).

They all take the grid's ``--out``/``--work``, filter its finished runs by method, task and seed, and measure each
selected run once into a JSON file beside the report, resumably; this is that command line, that filter and
that loop, so each tool only says what it measures.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

from .results import ResultsFile, RunRecord
from .specs import specs_of_grid


def add_run_filters(p: argparse.ArgumentParser, methods: str, methods_help: str = "methods to measure") -> None:
    p.add_argument("--out", type=Path, required=True, help="the grid's --out directory")
    p.add_argument("--work", type=Path, default=Path("outputs/bench"), help="the grid's --work directory")
    p.add_argument("--methods", default=methods, help=f"{methods_help} (comma-separated; default {methods})")
    p.add_argument("--tasks", default="", help="only these tasks (comma-separated; default: all)")
    p.add_argument("--seeds", default="", help="only these seeds (comma-separated; default: all)")


def finished_runs(args: argparse.Namespace, need: tuple[str, ...] = ()) -> list[RunRecord]:
    """The grid's finished runs (records of ``results.jsonl``) that pass the filters and measured every field of
    ``need``, sorted by run key."""
    tasks = {t for t in args.tasks.split(",") if t}
    seeds = {int(s) for s in args.seeds.split(",") if s}
    methods = set(args.methods.split(","))
    records = [r for r in ResultsFile(args.out / "results.jsonl").ok().values()
               if r.method in methods and all(getattr(r, k) is not None for k in need)
               and (not tasks or r.task in tasks) and (not seeds or r.seed in seeds)]
    return sorted(records, key=lambda r: r.key)


def no_runs_message(tool: str, args: argparse.Namespace, grid_methods: list[str] | None = None) -> None:
    """Say on stderr that the filters matched nothing, and what to check."""
    given = [f for f in (args.tasks and f"--tasks {args.tasks}", args.seeds and f"--seeds {args.seeds}") if f]
    ran = f" (the grid ran methods {', '.join(grid_methods)})" if grid_methods else ""
    print(f"{tool}: no finished run of --methods {args.methods}{' with ' + ' and '.join(given) if given else ''} "
          f"in {args.out / 'results.jsonl'}{ran}; nothing measured, nothing written. Check the filters, or run the "
          "grid first.", file=sys.stderr)


def measure_runs(tool: str, args: argparse.Namespace, measure: Callable, measured: Callable[[dict], bool],
                 progress: Callable[[str, dict], str]) -> dict[str, dict] | None:
    """Measure each finished run the filters select, by run key, into ``<out>/<tool>.json``.

    ``measure(spec)`` gives a run's entry; runs whose saved entry ``measured`` accepts are skipped, and the file
    is rewritten after each run, so an interrupted pass keeps what it measured and the next one resumes. Prints
    ``progress(key, entry)`` per run measured. None (after saying why) when the filters match no finished run.
    """
    records = finished_runs(args)
    if not records:
        no_runs_message(tool, args)
        return None
    done_path = args.out / f"{tool}.json"
    done = json.loads(done_path.read_text()) if done_path.exists() else {}
    specs = specs_of_grid(args.out, args.work)
    for r in records:
        spec = specs.get(r.key)
        if spec is None or (r.key in done and measured(done[r.key])):
            continue
        done[r.key] = measure(spec)
        done_path.write_text(json.dumps(done, indent=1))
        print(progress(r.key, done[r.key]), flush=True)
    return done
