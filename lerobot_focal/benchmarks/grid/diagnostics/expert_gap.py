"""Where do a grid run's failures leave the demonstrator? On-policy disagreement with MetaWorld's scripted expert.

    lerobot-focal-bench expert-gap --out docs/benchmarks/grid_cpu_plateau \
        --tasks basketball --seeds 0

Success rates say how often a policy fails, not where. This rolls out a finished run's final checkpoint through
LeRobot's own ``rollout`` (what ``lerobot-eval`` runs: the checkpoint's processors and the env config it was
trained and evaluated with) and, at every state the policy visits, asks the scripted MetaWorld expert that
recorded the demos what it would do there. Per run:

* how many failed episodes never held the object (MetaWorld's own ``grasp_success`` never set): failures at the
  grasp, as opposed to after it;
* the mean |policy − expert| per action dimension (x, y, z, gripper) over windows of the episode, successes and
  failures apart: where along the episode the policy leaves the demonstrated behaviour;
* success of the episodes whose placement (object and goal positions at reset) lies inside the range the demos
  cover in every coordinate, against those outside it in at least one: the range the min-max normaliser was fit
  on, so "outside" is an input the network never saw in [−1, 1];
* dither: the mean |a_{t+1} − a_t| per dimension (the paper's ATV, per dimension), successes and failures apart,
  split into the steps where a new chunk starts (a re-plan) and the steps inside a chunk, beside the expert's
  own change along the same states. A policy that jitters only at re-plans switches between sampled modes from
  one chunk to the next; one that jitters inside its chunks predicts jagged chunks; an expert that changes as
  much says the states themselves call for it.

The expert's answers at states the demos never visited (the policy's own mistakes) are DAgger's labels, not what
the policy was trained on: a gap that opens after a missed grasp and stays says the demos hold no recovery to
imitate. Episodes use their own seeds (``EXPERT_GAP_SEED + 1000·seed + i``), which no periodic evaluation, demo,
held-out or fresh episode uses. Writes ``expert_gap.json``, ``expert_gap.md`` and ``expert_gap.png`` beside the
grid's report; runs already measured with as many episodes are skipped. Low-dimensional runs take seconds each.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ....console import doc_parser
from ....figures import save_png
from ..revisit import add_run_filters, measure_runs
from ..seeds import EXPERT_GAP_SEED
from ..specs import checkpoint_of

#: Coordinates of MetaWorld's 39-d observation that a reset randomises: first and second object position, goal.
PLACEMENT_DIMS = (*range(4, 7), *range(11, 14), *range(36, 39))
WINDOW = 25  # steps per row of the gap table
DIMS = ("x", "y", "z", "gripper")


def measure(
    checkpoint: Path, episodes: int, first_seed: int, metrics_path: Path, demo_stats: Path | None = None
) -> dict:
    """Roll the checkpoint out for ``episodes`` episodes with the expert's action recorded at every visited state.

    ``demo_stats``: the training dataset's ``meta/stats.json``; with it, each episode's placement is checked
    against the demos' range of ``observation.environment_state``."""
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.envs.factory import make_env, make_env_pre_post_processors
    from lerobot.scripts.lerobot_eval import rollout
    from lerobot.utils.random_utils import set_seed

    import lerobot_focal.envs  # noqa: F401  registers focal_metaworld, the env type the checkpoint names

    from ..analyze import load_policy

    policy, pre, post = load_policy(checkpoint)
    replan_every = int(policy.config.n_action_steps)  # LeRobot's action queue: a chunk every n_action_steps
    env_cfg = TrainPipelineConfig.from_pretrained(checkpoint).env
    if env_cfg is None or env_cfg.type != "focal_metaworld":
        raise SystemExit(f"expert_gap: {checkpoint} was not trained with a focal_metaworld env (the only one with a "
                         "scripted expert); nothing to compare with")
    metrics_path.unlink(missing_ok=True)
    env_cfg.metrics_path = str(metrics_path)  # never the run's own episode files
    (vec,) = [v for suite in make_env(env_cfg, n_envs=episodes).values() for v in suite.values()]
    env_pre, env_post = make_env_pre_post_processors(env_cfg, policy.config)
    expert: list[np.ndarray] = []  # [t]: the expert's action at the state action t was taken in
    grasped: list[np.ndarray] = []  # [t + 1]: MetaWorld's grasp_success after action t
    start_obs: list[np.ndarray] = []  # MetaWorld's 39-d observation right after reset

    def record(env) -> None:  # LeRobot calls it after reset and after every step
        if not start_obs:
            start_obs.append(np.stack(env.call("last_raw_obs")))
        expert.append(np.stack(env.call("expert_action")))
        grasped.append(np.asarray(env.call("object_grasped"), dtype=bool))

    set_seed(first_seed)  # the policy's noise draws too, as lerobot-eval seeds them: reruns give the same numbers
    try:  # rollout runs the policy under torch.inference_mode itself
        out = rollout(vec, policy, env_pre, env_post, pre, post,
                      seeds=[first_seed + i for i in range(episodes)], render_callback=record)
    finally:
        vec.close()
    actions = np.clip(out["action"].numpy(), -1.0, 1.0)  # MetaWorld clips what it is given; the expert too
    steps = actions.shape[1]
    expert_actions = np.clip(np.stack(expert[:steps], axis=1), -1.0, 1.0)  # (B, T, 4)
    gap = np.abs(actions - expert_actions)
    last = out["done"].int().argmax(dim=1).numpy()  # LeRobot's own "valid steps" rule: up to the first done
    success = out["success"].any(dim=1).numpy()
    held = np.stack(grasped[1:steps + 1], axis=1)
    out = summarise(gap, last, success, np.array([held[b, : last[b] + 1].any() for b in range(len(last))]))
    out["dither"] = dither(actions, expert_actions, last, success, replan_every)
    if demo_stats is not None and demo_stats.exists():
        stats = json.loads(demo_stats.read_text()).get("observation.environment_state")
        if stats is not None:
            low, high = np.asarray(stats["min"]), np.asarray(stats["max"])
            out["placement"] = placement_split(start_obs[0], low, high, success)
    return out


def placement_split(start: np.ndarray, low: np.ndarray, high: np.ndarray, success: np.ndarray) -> dict:
    """Successes / episodes with every randomised coordinate inside the demos' [low, high] and with any outside.

    Coordinates the demos never varied (a second object some tasks lack) are left out: they are not placements."""
    dims = [d for d in PLACEMENT_DIMS if high[d] - low[d] > 1e-6]
    outside = ((start[:, dims] < low[dims] - 1e-6) | (start[:, dims] > high[dims] + 1e-6)).any(axis=1)
    return {"inside": [int(success[~outside].sum()), int((~outside).sum())],
            "outside": [int(success[outside].sum()), int(outside.sum())]}


def summarise(gap: np.ndarray, last: np.ndarray, success: np.ndarray, ever_grasped: np.ndarray) -> dict:
    """Per-window mean gap of successes and failures: episodes weigh equally, each over its own steps in it."""
    valid = np.arange(gap.shape[1])[None, :] <= last[:, None]
    windows = {}
    for name, sel in (("success", success), ("failure", ~success)):
        rows = []
        for start in range(0, gap.shape[1], WINDOW):
            per_episode = [gap[b, start:start + WINDOW][valid[b, start:start + WINDOW]].mean(axis=0)
                           for b in np.flatnonzero(sel) if valid[b, start:start + WINDOW].any()]
            if per_episode:
                rows.append({"start": start, "episodes": len(per_episode),
                             "gap": [round(float(x), 4) for x in np.mean(per_episode, axis=0)]})
        windows[name] = rows
    return {"episodes": int(len(success)), "successes": int(success.sum()),
            "failures_never_grasped": int((~success & ~ever_grasped).sum()),
            "successes_never_grasped": int((success & ~ever_grasped).sum()), "windows": windows}


def dither(actions: np.ndarray, expert: np.ndarray, last: np.ndarray, success: np.ndarray,
           replan_every: int) -> dict:
    """Mean |a_{t+1} − a_t| per action dimension over each episode's valid steps (episodes weigh equally),
    successes and failures apart: at the first step of a chunk (t a multiple of ``replan_every``: LeRobot's
    queue re-plans there), inside chunks, and the expert's actions along the same states."""
    t = np.arange(1, actions.shape[1])  # the change into step t
    change = {"policy": np.abs(np.diff(actions, axis=1)), "expert": np.abs(np.diff(expert, axis=1))}
    parts = {"replan": ("policy", t % replan_every == 0), "within": ("policy", t % replan_every != 0),
             "expert": ("expert", np.ones_like(t, dtype=bool))}
    out: dict = {"replan_every": replan_every}
    for name, sel in (("success", success), ("failure", ~success)):
        rows = {}
        for part, (source, at) in parts.items():
            per_episode = [change[source][b, at & (t <= last[b])].mean(axis=0) for b in np.flatnonzero(sel)
                           if (at & (t <= last[b])).any()]
            if per_episode:
                rows[part] = [round(float(x), 4) for x in np.mean(per_episode, axis=0)]
        out[name] = rows
    return out


def render(done: dict[str, dict]) -> str:
    md = ["# Where failures leave the expert (on-policy disagreement)", "",
          "`lerobot-focal-bench expert-gap --out <grid>`: each run's final checkpoint rolled out "
          "by LeRobot's `rollout` on episodes of its own; at every visited state MetaWorld's scripted expert (the "
          "demonstrator) is asked what it would do. Mean |policy − expert| per action dimension, actions in "
          "[−1, 1]; \"never held\" = MetaWorld's `grasp_success` was never set. Its episodes are its own (20 by "
          "default), so its success counts scatter around the grid's fresh-episode number.", ""]
    md += ["## Summed over seeds", "",
           "| task · method | episodes that succeed | failures that never held the object | success, placement "
           "inside the demos' range | success, placement outside it in ≥ 1 coordinate |", "|---|---|---|---|---|"]
    for run, v in sorted(task_totals(done).items()):
        cells = [f"{a} / {b}" if (a, b) != (None, None) else "–"
                 for a, b in (v.get(k, (None, None)) for k in ("success", "never_held", "inside", "outside"))]
        md.append(f"| {run} | " + " | ".join(cells) + " |")
    md.append("")
    md += _dither_table(done)
    for key in sorted(done):
        r = done[key]
        failures = r["episodes"] - r["successes"]
        md += [f"## {key.replace('|', ' · ')}", "",
               f"{r['successes']} of {r['episodes']} episodes succeed; {r['failures_never_grasped']} of the "
               f"{failures} failures never held the object." + _placement_text(r.get("placement")), "",
               "| steps | successes (n): " + " · ".join(DIMS) + " | failures (n): " + " · ".join(DIMS) + " |",
               "|---|---|---|"]
        by_start = {}
        for name in ("success", "failure"):
            for row in r["windows"][name]:
                by_start.setdefault(row["start"], {})[name] = row
        for start in sorted(by_start):
            cells = []
            for name in ("success", "failure"):
                row = by_start[start].get(name)
                if row is None:
                    cells.append("–")
                else:
                    cells.append(f"({row['episodes']}) " + " · ".join(f"{g:.2f}" for g in row["gap"]))
            md.append(f"| {start}-{start + WINDOW - 1} | {cells[0]} | {cells[1]} |")
        md.append("")
    return "\n".join(md)


def _dither_table(done: dict[str, dict]) -> list[str]:
    runs = {key: r["dither"] for key, r in sorted(done.items()) if "dither" in r}
    if not runs:
        return []
    md = ["## Dither: mean |a(t+1) − a(t)| per dimension (" + " · ".join(DIMS) + ")", "",
          "Each episode over its own steps; *at re-plan*: the first action of a new chunk against the last of the "
          "previous one; *inside chunks*: the other steps; *expert*: the scripted expert's actions along the same "
          "states (how much the states themselves call for).", "",
          "| run | re-plan every | successes: at re-plan | inside chunks | expert | failures: at re-plan | "
          "inside chunks | expert |", "|---|---|---|---|---|---|---|---|"]
    for key, d in runs.items():
        cells = [" · ".join(f"{x:.2f}" for x in d[name][part]) if part in d[name] else "–"
                 for name in ("success", "failure") for part in ("replan", "within", "expert")]
        md.append(f"| {key.replace('|', ' · ')} | {d['replan_every']} | " + " | ".join(cells) + " |")
    return [*md, ""]


def _placement_text(split: dict | None) -> str:
    if split is None:
        return ""
    (si, ni), (so, no) = split["inside"], split["outside"]
    return (f" Placement inside the demos' range: {si} of {ni} succeed; outside it in at least one coordinate: "
            f"{so} of {no}.")


def task_totals(done: dict[str, dict]) -> dict[str, dict[str, list[int]]]:
    """Per task and method, summed over seeds: successes / episodes, failures that never held the object /
    failures, and the placement split (when measured)."""
    totals: dict[str, dict[str, list[int]]] = {}
    for key, r in done.items():
        task, method, _seed = key.split("|")
        t = totals.setdefault(f"{task} · {method}", {"success": [0, 0], "never_held": [0, 0]})
        failures = r["episodes"] - r["successes"]
        for name, pair in (("success", (r["successes"], r["episodes"])),
                           ("never_held", (r["failures_never_grasped"], failures)),
                           *((side, r["placement"][side]) for side in ("inside", "outside") if "placement" in r)):
            t[name] = [a + b for a, b in zip(t.get(name, [0, 0]), pair, strict=True)]
    return totals


def _mean_windows(runs: list[dict], name: str) -> tuple[list[float], np.ndarray]:
    """Window centres and the gap per dimension averaged over runs (each run's window counts once)."""
    by_start: dict[int, list[list[float]]] = {}
    for r in runs:
        for row in r["windows"][name]:
            by_start.setdefault(row["start"], []).append(row["gap"])
    starts = sorted(by_start)
    return [s + WINDOW / 2 for s in starts], np.array([np.mean(by_start[s], axis=0) for s in starts])


def plot(done: dict[str, dict], path: Path) -> None:
    """One row per task, one column per action dimension; a colour per method, failures solid, successes dashed,
    each the mean over the method's seeds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs: dict[str, dict[str, list[dict]]] = {}
    for key, r in done.items():
        task, method, _seed = key.split("|")
        runs.setdefault(task, {}).setdefault(method, []).append(r)
    methods = sorted({m for per_task in runs.values() for m in per_task})
    colours = {m: f"C{i}" for i, m in enumerate(methods)}
    tasks = sorted(runs)
    fig, axes = plt.subplots(len(tasks), len(DIMS), figsize=(3.2 * len(DIMS), 2.4 * len(tasks)), squeeze=False,
                             sharey=True)
    for row, task in zip(axes, tasks, strict=True):
        for method, method_runs in sorted(runs[task].items()):
            for name, style, plural in (("failure", "-", "failures"), ("success", "--", "successes")):
                x, gaps = _mean_windows(method_runs, name)
                for d, ax in enumerate(row):
                    if len(x):
                        ax.plot(x, gaps[:, d], style, marker="o", ms=3, color=colours[method],
                                label=f"{method}, {plural}" if d == 0 else None)
        for d, ax in enumerate(row):
            ax.set_title(f"{task}: {DIMS[d]}", fontsize=9)
            ax.grid(alpha=0.3)
        row[0].set_ylabel("|policy − expert|")
    axes[0][0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("episode step")
    save_png(fig, path, dpi=100)


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench expert-gap")
    add_run_filters(p, "focal")
    p.add_argument("--episodes", type=int, default=20, help="episodes per run (default 20)")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes must be at least 1, got {args.episodes}")

    def measure_run(spec) -> dict:
        return measure(checkpoint_of(spec.run_dir), args.episodes, EXPERT_GAP_SEED + 1000 * spec.seed,
                       spec.run_dir / "expert_gap_episodes.jsonl", spec.data.train_root / "meta" / "stats.json")

    # Entries measured before the dither summary existed keep their numbers (their checkpoints may be gone).
    done = measure_runs("expert_gap", args, measure_run, lambda e: e.get("episodes") == args.episodes,
                        lambda key, e: f"{key}: {e['successes']} / {args.episodes} succeed, "
                                       f"{e['failures_never_grasped']} failures never held the object")
    if done is None:
        return 2
    (args.out / "expert_gap.md").write_text(render(done))
    plot(done, args.out / "expert_gap.png")
    print(render(done))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
