"""What executing in chunks costs by itself: MetaWorld's scripted expert, run the way the policy runs.

    lerobot-focal-bench execution-cost                     # the five development tasks, 20 episodes per variant
    lerobot-focal-bench execution-cost --tasks pick-place --episodes 50 --noise 0.05 0.1 0.3

A policy that imitated the expert perfectly would still differ from it in how it acts: focal predicts H = 4
actions at the first state of each chunk and executes them open loop, and its actions carry an error. This
measures how much success each of those costs the *expert* (the demonstrator the policy imitates), on every
development task, so a grid's miss can be split into what the execution costs and what the learning does:

* ``closed``: the expert closed loop, one action per state (how the demos were recorded);
* ``chunked``: the expert's own next H actions computed at each chunk's first state and executed open loop. The
  expert is reactive, so "its next H actions" are what it does closed loop from that state; a shadow env
  replays the episode's executed actions from the same reset seed to that state and runs the expert H steps
  ahead there (MuJoCo is deterministic, so the replay reaches the same state). Without noise this equals
  ``closed`` exactly, which the report checks;
* ``hold``: the expert's action at the chunk's first state repeated H times (a chunk that ignores the expert's
  own dynamics: a lower bound, not how focal acts);
* each with Gaussian noise of standard deviation σ added to every executed action (then clipped to [−1, 1]):
  the policy's error, which closed loop the expert corrects at the next step and open loop only at the next
  chunk.

Reported per task and variant: success (episodes of ``--episode-length`` steps, success at any step, MetaWorld's
own signal) and, for the failures, how many never held the object (MetaWorld's ``grasp_success``). Episodes use
reset seeds ``EXECUTION_COST_SEED + i``, which no demo, evaluation or held-out episode of the grid uses (the
grid's ranges: `lerobot_focal.benchmarks.grid.seeds`). Writes ``execution_cost.{json,md,png}`` under ``--out``.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from lerobot_focal.console import doc_parser
from lerobot_focal.figures import save_png

from .cloud_content import DEV_TASKS

#: First reset seed of this diagnostic's episodes (the grid's ranges end below 500 000 or start at 1 000 000).
EXECUTION_COST_SEED = 600_000
CHUNK = 4  # focal's H: actions executed per network evaluation


@dataclass(frozen=True)
class Variant:
    mode: str  # closed | chunked | hold
    noise: float

    @property
    def name(self) -> str:
        return f"{self.mode} σ={self.noise:g}"


@dataclass
class Outcome:
    task: str
    variant: str
    mode: str
    noise: float
    episodes: int
    successes: int
    failures_never_held: int
    wall_s: float
    # chunked σ=0 only: largest |action − closed-loop action| over its episodes (0: the replay is exact)
    max_action_gap_to_closed: float | None = None

    @property
    def success(self) -> float:
        return 100.0 * self.successes / self.episodes


def _make_env(task: str, episode_length: int):
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    cfg = FocalMetaworldEnvConfig(task=task, obs_type="state", env_state=True, render_videos=False,
                                  episode_length=episode_length)
    return cfg.make_single_env()


def _expert_plan(shadow, seed: int, executed: list[np.ndarray], horizon: int) -> list[np.ndarray]:
    """The expert's next `horizon` closed-loop actions from the state `executed` leads to from `seed`'s reset."""
    shadow.reset(seed=seed)
    for action in executed:
        shadow.step(action)
    plan = []
    for _ in range(horizon):
        action = shadow.expert_action()
        plan.append(action)
        shadow.step(action)
    return plan


def run_episode(env, shadow, seed: int, variant: Variant, episode_length: int, rng: np.random.Generator,
                chunk: int = CHUNK) -> tuple[bool, bool, list[np.ndarray]]:
    """One episode; returns (success, object ever held, the executed actions)."""
    env.reset(seed=seed)
    executed: list[np.ndarray] = []
    held = False
    plan: list[np.ndarray] = []
    for t in range(episode_length):
        if variant.mode == "closed":
            action = env.expert_action()
        else:
            if t % chunk == 0:
                if variant.mode == "hold":
                    plan = [env.expert_action()] * chunk
                else:
                    plan = _expert_plan(shadow, seed, executed, chunk)
            action = plan[t % chunk]
        if variant.noise > 0:
            action = np.clip(action + rng.normal(0.0, variant.noise, size=action.shape), -1.0, 1.0)
        action = np.asarray(action, dtype=np.float32)
        executed.append(action)
        _, _, terminated, truncated, info = env.step(action)
        held |= bool(info.get("grasp_success", 0))
        if info["is_success"]:
            return True, held, executed
        if truncated:
            break
    return False, held, executed


def measure(task: str, variants: list[Variant], episodes: int, episode_length: int) -> list[Outcome]:
    import warnings

    warnings.filterwarnings("ignore", message="Constant\\(s\\) may be too high")  # the experts' gains, by design
    env, shadow = _make_env(task, episode_length), _make_env(task, episode_length + CHUNK)  # plans run past the end
    out = []
    closed_actions: dict[int, np.ndarray] = {}
    try:
        for variant in variants:
            start = time.perf_counter()
            successes = never_held = 0
            gap = None
            for i in range(episodes):
                rng = np.random.default_rng([EXECUTION_COST_SEED + i, int(variant.noise * 1000)])
                ok, held, actions = run_episode(env, shadow, EXECUTION_COST_SEED + i, variant, episode_length, rng)
                successes += ok
                never_held += (not ok) and (not held)
                if variant == Variant("closed", 0.0):
                    closed_actions[i] = np.stack(actions)
                elif variant == Variant("chunked", 0.0) and i in closed_actions:
                    gap = max(gap or 0.0, _action_gap(np.stack(actions), closed_actions[i]))
            outcome = Outcome(task, variant.name, variant.mode, variant.noise, episodes, successes, never_held,
                              round(time.perf_counter() - start, 1), gap)
            print(f"[execution-cost] {task:12s} {variant.name:14s} {outcome.success:5.1f} % "
                  f"({successes}/{episodes}; {never_held} failures never held the object) {outcome.wall_s:.0f} s",
                  flush=True)
            out.append(outcome)
    finally:
        env.close()
        shadow.close()
    return out


def _action_gap(a: np.ndarray, b: np.ndarray) -> float:
    if a.shape != b.shape:  # one episode ended earlier than the other
        return float("inf")
    return float(np.abs(a - b).max())


def variants_for(noises: list[float]) -> list[Variant]:
    """closed and chunked at σ = 0 and every noise level, hold at σ = 0 (chunked σ = 0 checks the replay)."""
    out = [Variant("closed", 0.0), Variant("chunked", 0.0), Variant("hold", 0.0)]
    for sigma in noises:
        out += [Variant("closed", sigma), Variant("chunked", sigma)]
    return out


def write_report(outcomes: list[Outcome], out: Path, command: str, episode_length: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    rows = [{**asdict(o), "success": round(o.success, 1)} for o in outcomes]
    (out / "execution_cost.json").write_text(json.dumps(
        {"command": command, "chunk": CHUNK, "episode_length": episode_length, "first_seed": EXECUTION_COST_SEED,
         "results": rows}, indent=2) + "\n")
    tasks = list(dict.fromkeys(o.task for o in outcomes))
    names = list(dict.fromkeys(o.variant for o in outcomes))
    by = {(o.task, o.variant): o for o in outcomes}
    lines = [
        "# What executing in chunks costs the scripted expert",
        "",
        f"`{command}`: MetaWorld's scripted expert on episodes of {episode_length} steps (reset seeds "
        f"{EXECUTION_COST_SEED} + i), run closed loop, in open-loop chunks of its own next {CHUNK} actions, or "
        f"holding its first action for {CHUNK} steps, with Gaussian noise σ on every executed action. Success %; in "
        "brackets the failures that never held the object (MetaWorld's `grasp_success`). See "
        "`lerobot_focal/benchmarks/execution_cost.py` for what each variant does.",
        "",
        "| task | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for task in tasks:
        cells = []
        for name in names:
            o = by.get((task, name))
            cells.append("–" if o is None else f"{o.success:.0f} ({o.failures_never_held})")
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    means = [np.mean([by[(t, n)].success for t in tasks if (t, n) in by]) for n in names]
    lines.append("| **mean** | " + " | ".join(f"**{m:.1f}**" for m in means) + " |")
    gaps = {t: by[(t, "chunked σ=0")].max_action_gap_to_closed for t in tasks if (t, "chunked σ=0") in by}
    if gaps:
        exact = all(g == 0.0 for g in gaps.values())
        lines += ["", "Replay check (chunked σ=0 against closed σ=0, largest action difference over the episodes): "
                  + ("0 on every task: the shadow env's replay reaches the executed state exactly." if exact
                     else ", ".join(f"{t} {g:.3g}" for t, g in gaps.items()) + ".")]
    (out / "execution_cost.md").write_text("\n".join(lines) + "\n")
    _plot(outcomes, tasks, out / "execution_cost.png")


def _plot(outcomes: list[Outcome], tasks: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(tasks), figsize=(3.2 * len(tasks), 3.2), sharey=True, squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        for mode, marker in (("closed", "o"), ("chunked", "s")):
            pts = sorted((o.noise, o.success) for o in outcomes if o.task == task and o.mode == mode)
            if pts:
                ax.plot(*zip(*pts, strict=True), marker=marker, label=f"{mode} (H={CHUNK})" if mode == "chunked"
                        else mode)
        hold = [o.success for o in outcomes if o.task == task and o.mode == "hold"]
        if hold:
            ax.scatter([0.0], hold, marker="x", color="k", label=f"hold ×{CHUNK}", zorder=3)
        ax.set_title(task)
        ax.set_xlabel("action noise σ")
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("expert success %")
    axes[0][-1].legend(fontsize=8)
    save_png(fig, path)


def main(argv: list[str] | None = None) -> int:
    import sys

    parser = doc_parser(__doc__, "lerobot-focal-bench execution-cost")
    parser.add_argument("--tasks", nargs="+", default=list(DEV_TASKS))
    parser.add_argument("--episodes", type=int, default=20, help="episodes per task and variant")
    parser.add_argument("--noise", type=float, nargs="+", default=[0.1, 0.3], help="action noise levels σ (> 0)")
    parser.add_argument("--episode-length", type=int, default=200, help="steps per episode (the grid's: 200)")
    parser.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.episode_length < 1 or any(s <= 0 for s in args.noise):
        parser.error("--episodes and --episode-length must be ≥ 1 and every --noise > 0")
    command = "lerobot-focal-bench execution-cost " + " ".join(argv if argv is not None else sys.argv[2:])
    outcomes = []
    for task in args.tasks:
        outcomes += measure(task, variants_for(args.noise), args.episodes, args.episode_length)
        write_report(outcomes, args.out, command.strip(), args.episode_length)  # partial results as tasks land
    print(f"[execution-cost] wrote {args.out / 'execution_cost.md'}")
    return 0
