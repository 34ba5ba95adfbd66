"""`lerobot-focal-bench rescore`: a finished grid's final checkpoints scored the paper's way, without retraining.

    lerobot-focal-bench rescore --out docs/benchmarks/grid_cpu_plateau --work outputs/bench
    lerobot-focal-bench rescore --out DIR --methods focal,diffusion --tasks pick-place --blocks 15

Why: a grid whose periodic evaluations reset the same placements every time (``periodic_eval`` "fixed", as
LeRobot's `lerobot-train` does) has a top-5 close to its fresh-episode number, while the paper's numbers come
from DP3's runner, whose evaluations are independent draws of 20 episodes, so its top-5 picks the luckiest
draws. This evaluates each final checkpoint on ``blocks`` × N fresh episodes (N = the grid's episodes per
evaluation; seeds ``RESCORE_SEED + 1000·seed`` onwards, which nothing else uses, see seeds.py), and reports
the top-k of the block means (the paper's estimator for one checkpoint, the luck of the draw of episodes
included) and the mean over all of them (what the checkpoint is worth). It does not pick among checkpoints
(the grid keeps only the final one), so it measures the draw-of-episodes part of the paper's optimism only.

Writes ``rescore.json`` beside ``results.jsonl`` (resumable: runs already re-scored with as many episodes are
skipped) and re-renders the report, whose three-estimator table and ``summary.json`` (``top5_paper_*``) then
hold these numbers. Run it between grid invocations, not beside a running grid.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from ...console import doc_parser
from .metrics import top_k_mean
from .processes import run_logged
from .resume import seeded_records
from .revisit import add_run_filters, measure_runs
from .run import child_env, final_eval_command
from .seeds import PER_SEED_BLOCK, RESCORE_BLOCKS, RESCORE_SEED
from .specs import checkpoint_of


def block_scores(episodes: Sequence[dict], block: int, top_k: int) -> dict:
    """Top-k of the means of consecutive blocks of ``block`` episodes (in seed order), and the overall mean.

    Episodes are ordered by their reset seed first: `lerobot-eval` writes them as they finish, and a block is
    a fixed set of placements, as one periodic evaluation is."""
    ordered = sorted(episodes, key=lambda e: e["seed"])
    if not ordered or len(ordered) % block:
        raise ValueError(f"{len(ordered)} episodes do not make whole blocks of {block}")
    means = [sum(float(e["success"]) for e in ordered[i:i + block]) / block for i in range(0, len(ordered), block)]
    return {"blocks": means, "top_k": top_k_mean(means, top_k), "k": top_k,
            "mean": sum(float(e["success"]) for e in ordered) / len(ordered), "episodes": len(ordered),
            "episodes_per_block": block}


def rescore_command(spec, checkpoint: Path, episodes: int) -> list[str]:
    """The grid's final `lerobot-eval` of the checkpoint with the re-score's episodes and seeds instead."""
    replaced = {"--eval.n_episodes": str(episodes), "--eval.batch_size": str(min(episodes, 25)),
                "--seed": str(RESCORE_SEED + PER_SEED_BLOCK * spec.seed)}
    out = []
    for arg in final_eval_command(spec, checkpoint, name="rescore"):
        name = arg.split("=", 1)[0]
        out.append(f"{name}={replaced[name]}" if name in replaced else arg)
    return out


def measure(spec, blocks: int) -> dict:
    p = spec.preset
    episodes = blocks * p.eval_episodes
    path = spec.run_dir / "rescore_episodes.jsonl"
    path.unlink(missing_ok=True)  # of an interrupted re-score
    run_logged(rescore_command(spec, checkpoint_of(spec.run_dir), episodes), spec.run_dir / "rescore_eval.log",
               child_env(p), "lerobot-eval (re-score)")
    eps = seeded_records(path)
    if len(eps) != episodes:
        raise RuntimeError(f"expected {episodes} re-score episodes, found {len(eps)} in {path}")
    return {**block_scores(eps, p.eval_episodes, p.top_k), "first_seed": min(e["seed"] for e in eps)}


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench rescore")
    add_run_filters(p, "all", "methods to re-score ('all': every method of the grid)")
    p.add_argument("--blocks", type=int, default=RESCORE_BLOCKS,
                   help=f"blocks of N episodes per checkpoint (default {RESCORE_BLOCKS}, N = the grid's episodes per "
                        "evaluation)")
    args = p.parse_args(argv)
    grid = json.loads((args.out / "grid.json").read_text())
    if args.methods == "all":
        args.methods = ",".join(grid["methods"])
    n = args.blocks * grid["preset"]["eval_episodes"]
    if not 0 < n <= PER_SEED_BLOCK:
        raise SystemExit(f"--blocks {args.blocks} × {grid['preset']['eval_episodes']} episodes: keep it in 1 … "
                         f"{PER_SEED_BLOCK} (the re-score's seed range per training seed)")
    done = measure_runs("rescore", args, lambda spec: measure(spec, args.blocks),
                        measured=lambda entry: entry.get("episodes") == n,
                        progress=lambda key, e: f"{key}: top-{e['k']} of {len(e['blocks'])} blocks "
                                                f"{e['top_k']:.2f}, mean of {e['episodes']} episodes {e['mean']:.2f}")
    if done is None:
        return 2
    from .report import write_report

    print(f"[rescore] {len(done)} runs in {args.out / 'rescore.json'}; report: {write_report(args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
