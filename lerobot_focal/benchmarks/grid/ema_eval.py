"""Does focal act better with its EMA weights or its online weights at the grid's budget?

    python -m lerobot_focal.benchmarks.grid.ema_eval --out docs/benchmarks/grid_cpu_plateau --work outputs/bench

Run it between grid invocations, not beside a running grid (one heavy job at a time).

For every finished focal-family run of a grid with a fresh-episode evaluation, evaluates the same final
checkpoint on the same fresh episodes (same seeds) with ``--policy.use_ema_for_inference=false`` and compares it,
pair by pair, with the grid's number (EMA weights, the default). Writes ``ema_vs_online.json`` and
``ema_vs_online.md`` beside the grid's report; resumable (runs already compared are skipped).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .metrics import paired_difference
from .results import ResultsFile
from .run import _call, _env, final_eval_command


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m lerobot_focal.benchmarks.grid.ema_eval", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True, help="the grid's --out directory")
    p.add_argument("--work", type=Path, default=Path("outputs/bench"), help="the grid's --work directory")
    p.add_argument("--methods", default="focal,focal_online", help="focal-family methods to compare")
    args = p.parse_args(argv)

    from .driver import build_specs, parse_args

    grid = json.loads((args.out / "grid.json").read_text())
    done_path = args.out / "ema_vs_online.json"
    done = json.loads(done_path.read_text()) if done_path.exists() else {}
    records = [r for r in ResultsFile(args.out / "results.jsonl").ok().values()
               if r["method"] in args.methods.split(",") and "success_fresh" in r]
    grid_argv = ["--preset", grid["preset"]["name"], "--tasks", ",".join(grid["tasks"]), "--methods",
                 ",".join(grid["methods"]), "--out", str(args.out), "--work", str(args.work),
                 "--seeds", ",".join(map(str, grid["seeds"]))]
    for key, value in grid.get("overrides", {}).items():
        grid_argv += [f"--{key.replace('_', '-')}", str(value)]
    specs = {s.key: s for s in build_specs(parse_args(grid_argv))[0]}
    for r in records:
        if r["key"] in done or r["key"] not in specs:
            continue
        spec = specs[r["key"]]
        run_dir = spec.run_dir
        checkpoint = run_dir / "train" / "checkpoints" / "last" / "pretrained_model"
        cmd = [*final_eval_command(spec, checkpoint, name="online"), "--policy.use_ema_for_inference=false"]
        _call(cmd, run_dir / "online_eval.log", _env(spec.preset), "lerobot-eval (online weights)")
        eps = [json.loads(x) for x in (run_dir / "online_episodes.jsonl").read_text().splitlines() if x]
        eps = [e for e in eps if e.get("seed") is not None]
        done[r["key"]] = {"ema": r["success_fresh"], "online": sum(e["success"] for e in eps) / len(eps),
                          "episodes": len(eps)}
        done_path.write_text(json.dumps(done, indent=1))
        print(f"{r['key']}: EMA {done[r['key']]['ema']:.2f}, online {done[r['key']]['online']:.2f}", flush=True)
    keys = sorted(done)
    d = paired_difference([done[k]["ema"] for k in keys], [done[k]["online"] for k in keys])
    md = ["# Acting with the EMA or the online weights (final checkpoints, fresh episodes)", "",
          "`python -m lerobot_focal.benchmarks.grid.ema_eval --out <grid>`: each run's final checkpoint on the "
          "same fresh episodes with `use_ema_for_inference` true (the grid's number) and false.", "",
          "| run | episodes | EMA weights | online weights |", "|---|---|---|---|"]
    md += [f"| {k} | {done[k]['episodes']} | {done[k]['ema'] * 100:.0f} % | {done[k]['online'] * 100:.0f} % |"
           for k in keys]
    if d["n"]:
        ci = "" if d["lo"] != d["lo"] else f", 95 % interval [{d['lo'] * 100:+.1f}, {d['hi'] * 100:+.1f}]"
        md += ["", f"EMA − online: {d['mean'] * 100:+.1f} points over {d['n']} runs{ci} "
               f"(EMA better / equal / worse: {d['wins']} / {d['ties']} / {d['losses']})."]
    (args.out / "ema_vs_online.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
