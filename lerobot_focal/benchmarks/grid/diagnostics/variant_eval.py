"""Would focal's finished grid checkpoints act better with another inference setting?

    lerobot-focal-bench variant-eval --variant online --out docs/benchmarks/grid_cpu_plateau
    lerobot-focal-bench variant-eval --variant nfe4 --tasks basketball,pick-place --out ...

Run it between grid invocations, not beside a running grid (one heavy job at a time).

For every finished focal-family run of a grid with a fresh-episode evaluation, evaluates the same final
checkpoint on the same fresh episodes (same seeds) with the variant's `lerobot-eval` overrides and compares it,
pair by pair, with the grid's number (EMA weights, one network evaluation per chunk). Variants:

* ``online``: the online weights instead of the EMA (``--policy.use_ema_for_inference=false``), to choose the
  default at the grid's budget;
* ``nfe2`` / ``nfe4``: 2 or 4 Euler steps along the learned flow instead of one, to tell whether one-step
  generation is what limits a task, or what the network learned;
* ``exec8``: 8 of the 12 predicted actions executed per chunk instead of the proximal 4 (half the re-plans),
  to tell whether fewer re-plans help and how good the foresight part of the macro-trajectory is;
* ``noise0``: every chunk started from M_0 = 0 instead of fresh noise, to tell whether switching between
  sampled modes from one re-plan to the next is what makes a policy dither;
* ``gripper``: the gripper command snapped to the two levels the run's own demos use (``--env.gripper_levels``,
  read from the demos, e.g. 0 and 0.8 on disassemble), to tell how much of a grasping miss is a hesitant grip
  command rather than where the arm goes.

Writes ``variant_<name>.json`` and ``variant_<name>.md`` beside the grid's report; resumable (runs already
compared are skipped).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass

from ....console import doc_parser
from ..metrics import paired_difference
from ..processes import run_logged
from ..resume import seeded_records
from ..revisit import add_run_filters, finished_runs, no_runs_message
from ..run import child_env, final_eval_command
from ..specs import RunSpec, checkpoint_of, specs_of_grid


@dataclass(frozen=True)
class Variant:
    label: str  # what the compared column shows
    overrides: tuple[str, ...]  # lerobot-eval arguments on top of the grid's final evaluation
    # Arguments that depend on the run (its demos), added to ``overrides``.
    per_run: Callable[[RunSpec], tuple[str, ...]] | None = None

    def arguments(self, spec: RunSpec) -> tuple[str, ...]:
        return self.overrides + (self.per_run(spec) if self.per_run else ())


def demo_gripper_levels(spec: RunSpec) -> tuple[float, float]:
    """The two gripper commands (action[3]) of the run's training demos. MetaWorld's scripted experts command
    one of two levels per task (open / closed: 0 and 1 on pick-place, 0 and 0.8 on disassemble); demos with other
    values are refused, as snapping to two levels would not describe them."""
    import numpy as np
    import pyarrow.parquet as pq

    files = sorted((spec.data.train_root / "data").rglob("*.parquet"))
    if not files:
        raise FileNotFoundError(f"no demos under {spec.data.train_root / 'data'}: run the grid first")
    grip = np.concatenate([np.stack(pq.read_table(f, columns=["action"]).column("action").to_numpy(
        zero_copy_only=False))[:, 3] for f in files])
    levels = np.unique(np.round(grip, 4))
    if len(levels) != 2:
        raise ValueError(f"{spec.data.train_root}: the demos' gripper commands take {len(levels)} values "
                         f"({levels[:8].tolist()}...), not two levels; the gripper variant needs two")
    return float(levels[0]), float(levels[1])


def _snap_to_demo_levels(spec: RunSpec) -> tuple[str, ...]:
    low, high = demo_gripper_levels(spec)
    return (f"--env.gripper_levels=[{low},{high}]",)


VARIANTS: dict[str, Variant] = {
    "online": Variant("online weights", ("--policy.use_ema_for_inference=false",)),
    "nfe2": Variant("2 Euler steps", ("--policy.num_inference_steps=2",)),
    "nfe4": Variant("4 Euler steps", ("--policy.num_inference_steps=4",)),
    # 8 of the 12 predicted actions per evaluation (half the re-plans), as LeRobot's diffusion executes 8 of 16.
    "exec8": Variant("8 actions executed per chunk", ("--policy.n_action_steps=8",)),
    # Every chunk from M_0 = 0: one deterministic trajectory per observation instead of a fresh sample per re-plan.
    "noise0": Variant("starting noise 0", ("--policy.inference_noise_scale=0",)),
    "gripper": Variant("gripper snapped to the demos' two levels", (), per_run=_snap_to_demo_levels),
}
GRID_LABEL = "grid (EMA, 1 step)"


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench variant-eval")
    p.add_argument("--variant", choices=sorted(VARIANTS), required=True)
    add_run_filters(p, "focal,focal_online", "focal-family methods to compare")
    args = p.parse_args(argv)
    variant = VARIANTS[args.variant]

    grid = json.loads((args.out / "grid.json").read_text())
    done_path = args.out / f"variant_{args.variant}.json"
    done = json.loads(done_path.read_text()) if done_path.exists() else {}
    records = finished_runs(args, need=("success_fresh",))
    if not records and not done:
        no_runs_message("variant_eval", args, grid["methods"])
        return 2
    specs = specs_of_grid(args.out, args.work)
    for r in records:
        if r.key not in specs or "atv_variant" in done.get(r.key, {}):
            continue
        spec = specs[r.key]
        episodes_file = spec.run_dir / f"{args.variant}_episodes.jsonl"
        if r.key not in done:
            cmd = [*final_eval_command(spec, checkpoint_of(spec.run_dir), name=args.variant),
                   *variant.arguments(spec)]
            run_logged(cmd, spec.run_dir / f"{args.variant}_eval.log", child_env(spec.preset),
                       f"lerobot-eval ({variant.label})")
        elif not episodes_file.exists():
            continue  # compared by an earlier version that kept no ATV, and its episodes are gone
        eps = seeded_records(episodes_file)
        if not eps:
            raise RuntimeError(f"{r.key}: no seeded episodes in {episodes_file}; see {args.variant}_eval.log beside it")
        done[r.key] = {"grid": r.success_fresh, "variant": sum(e["success"] for e in eps) / len(eps),
                          "episodes": len(eps), "atv_grid": r.atv_fresh,
                          "atv_variant": sum(e["action_total_variation"] for e in eps) / len(eps)}
        done_path.write_text(json.dumps(done, indent=1))
        print(f"{r.key}: {GRID_LABEL} {done[r.key]['grid']:.2f}, {variant.label} "
              f"{done[r.key]['variant']:.2f}", flush=True)
    (args.out / f"variant_{args.variant}.md").write_text(render(args.variant, done))
    print(render(args.variant, done))
    return 0


def render(name: str, done: dict[str, dict]) -> str:
    variant = VARIANTS[name]
    keys = sorted(done)
    md = [f"# The grid's final checkpoints with {variant.label} (fresh episodes)", "",
          f"`lerobot-focal-bench variant-eval --variant {name} --out <grid>`: each run's final "
          f"checkpoint on the same fresh episodes as the grid's number, with "
          f"`{' '.join(variant.overrides) or 'per-run ' + variant.label}`.", "",
          f"| run (task · method · seed) | episodes | {GRID_LABEL} | {variant.label} | ATV, grid | ATV, variant |",
          "|---|---|---|---|---|---|"]
    md += [f"| {k.replace('|', ' · ')} | {done[k]['episodes']} | {done[k]['grid'] * 100:.0f} % "
           f"| {done[k]['variant'] * 100:.0f} % | {_atv(done[k].get('atv_grid'))} "
           f"| {_atv(done[k].get('atv_variant'))} |"
           for k in keys]
    d = paired_difference([done[k]["variant"] for k in keys], [done[k]["grid"] for k in keys])
    if d["n"]:
        ci = "" if d["lo"] != d["lo"] else f", 95 % interval [{d['lo'] * 100:+.1f}, {d['hi'] * 100:+.1f}]"
        md += ["", f"{variant.label} − grid: {d['mean'] * 100:+.1f} points over {d['n']} runs{ci} "
               f"(better / equal / worse: {d['wins']} / {d['ties']} / {d['losses']})."]
    atv = [k for k in keys if done[k].get("atv_grid") is not None and done[k].get("atv_variant") is not None]
    if atv:
        d = paired_difference([done[k]["atv_variant"] for k in atv], [done[k]["atv_grid"] for k in atv])
        md += ["", f"ATV (mean change of consecutive executed actions, fresh episodes), {variant.label} − grid: "
               f"{d['mean']:+.4f} over {d['n']} runs"
               + ("" if d["lo"] != d["lo"] else f", 95 % interval [{d['lo']:+.4f}, {d['hi']:+.4f}]")
               + f" (lower / equal / higher: {d['losses']} / {d['ties']} / {d['wins']})."]
    return "\n".join(md) + "\n"


def _atv(x: float | None) -> str:
    return "–" if x is None else f"{x:.3f}"


if __name__ == "__main__":
    raise SystemExit(main())
