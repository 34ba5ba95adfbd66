"""Every MetaWorld reset seed a grid run uses, by purpose, and the check that no two purposes share one.

A MetaWorld reset seed fixes the object and goal placement, so an evaluation episode whose seed a demo used
evaluates on training data, and two estimators that share seeds are not independent. Each purpose gets its own
half-open range per training seed; ``check_seed_ranges`` refuses a grid whose ranges overlap (another
``--demo-seed``, more demos, more evaluations), before anything runs.

* periodic evaluations, ``fixed`` (LeRobot's default): seeds ``k … k + N − 1`` at every evaluation of seed k;
* periodic evaluations, ``fresh`` (DP3's runner: new placements at every reset): evaluation i of seed k uses
  ``PERIODIC_FRESH_SEED + PERIODIC_FRESH_BLOCK·k + i·N + k …`` (the env adds the offset, see
  ``FocalMetaworldEnvConfig.fresh_reset_seeds``);
* demos: ``demo_seed …`` for every seed, or ``demo_seed + DEMO_SEED_STRIDE·k …`` with ``demos_per_seed``;
* held-out demos (open-loop metrics): ``HELDOUT_SEED …``, shared by every seed;
* final checkpoint on fresh episodes: ``FINAL_EVAL_SEED + 1000·k …``;
* expert_gap's episodes: ``EXPERT_GAP_SEED + 1000·k …``;
* re-score (``lerobot-focal-bench rescore``): ``RESCORE_SEED + 1000·k …``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ...datasets.making.collect import ATTEMPTS_PER_EPISODE
from .grid_presets import DEMO_SEED, DEMO_SEED_END, GridPreset

#: The fresh periodic evaluations of seed k start at PERIODIC_FRESH_SEED + PERIODIC_FRESH_BLOCK·k: above every
#: other range, with room for PERIODIC_FRESH_BLOCK episodes per seed (the paper's 24 × 20 = 480 need a twentieth).
PERIODIC_FRESH_SEED = 1_000_000
PERIODIC_FRESH_BLOCK = 10_000
#: With ``demos_per_seed``, seed k's demos start at demo_seed + DEMO_SEED_STRIDE·k (seed 1 of the default draws
#: the placements of ``--demo-seed 2000``, the grid's earlier "another draw of the demos" diagnostic).
DEMO_SEED_STRIDE = 1_000
#: Held-out demos (the open-loop metrics' episodes) start here, right above the demos' range, for every seed.
HELDOUT_SEED = DEMO_SEED_END
#: The final fresh-episode evaluation of seed k starts at FINAL_EVAL_SEED + 1000·k, far from the periodic
#: evaluations (seeds k…), the demos and the held-out set.
FINAL_EVAL_SEED = 200_000
#: expert_gap's episodes of seed k start at EXPERT_GAP_SEED + 1000·k.
EXPERT_GAP_SEED = 300_000
#: Re-scoring a final checkpoint (15 blocks × 20 episodes by default) uses RESCORE_SEED + 1000·k onwards.
RESCORE_SEED = 400_000
#: The re-score's blocks per run (of N = the preset's eval_episodes each), as the paper's protocol takes top-5 of
#: evaluations of 20 episodes: 15 × 20 = 300 episodes of the final checkpoint.
RESCORE_BLOCKS = 15
#: Episodes per seed the tools with a 1000-wide range per seed (final evaluation, expert_gap, re-score) may use.
PER_SEED_BLOCK = 1_000
#: expert_gap's episodes per run are at most this many (its range per seed is PER_SEED_BLOCK wide).
EXPERT_GAP_EPISODES = 100


@dataclass(frozen=True)
class SeedRange:
    purpose: str
    start: int
    stop: int  # exclusive

    def overlaps(self, other: SeedRange) -> bool:
        return self.start < other.stop and other.start < self.stop


def demo_seed_of(preset: GridPreset, seed: int) -> int:
    """First reset seed of the training demos of training seed ``seed``."""
    return preset.demo_seed + (DEMO_SEED_STRIDE * seed if preset.demos_per_seed else 0)


def fresh_offset(preset: GridPreset, seed: int) -> int:
    """What the env adds to LeRobot's reset seeds (k …) at a run's first fresh periodic evaluation."""
    return PERIODIC_FRESH_SEED + PERIODIC_FRESH_BLOCK * seed


def run_seed_ranges(preset: GridPreset, seed: int, rescore_episodes: int = 0) -> list[SeedRange]:
    """Every range of reset seeds training seed ``seed`` of a grid with ``preset`` may use."""
    n_evals = preset.steps // preset.eval_every
    if preset.periodic_eval == "fresh":
        first = fresh_offset(preset, seed) + seed
        periodic = SeedRange("periodic evaluations (fresh)", first, first + n_evals * preset.eval_episodes)
    else:
        periodic = SeedRange("periodic evaluations (fixed)", seed, seed + preset.eval_episodes)
    demo = demo_seed_of(preset, seed)
    ranges = [
        periodic,
        SeedRange("demos", demo, demo + ATTEMPTS_PER_EPISODE * preset.demos),  # as many as collection may try
        SeedRange("held-out demos", HELDOUT_SEED, HELDOUT_SEED + ATTEMPTS_PER_EPISODE * preset.heldout_demos),
        SeedRange("final evaluation", FINAL_EVAL_SEED + PER_SEED_BLOCK * seed,
                  FINAL_EVAL_SEED + PER_SEED_BLOCK * seed + preset.final_episodes),
        SeedRange("expert_gap", EXPERT_GAP_SEED + PER_SEED_BLOCK * seed,
                  EXPERT_GAP_SEED + PER_SEED_BLOCK * seed + EXPERT_GAP_EPISODES),
    ]
    if rescore_episodes:
        ranges.append(SeedRange("re-score", RESCORE_SEED + PER_SEED_BLOCK * seed,
                                RESCORE_SEED + PER_SEED_BLOCK * seed + rescore_episodes))
    return ranges


def check_seed_ranges(preset: GridPreset, seeds: Sequence[int], rescore_episodes: int = 0) -> None:
    """Raise SystemExit, naming both ranges, if two purposes (of any two training seeds) could share a reset seed.

    Periodic evaluations in ``fixed`` mode are shared by design (seed k evaluates k … k + N − 1), so those of two
    training seeds may overlap each other; nothing else may overlap anything. Demos must also stay in
    [DEMO_SEED, DEMO_SEED_END), and the ranges that are 1000 wide per seed must not run into the next seed's."""
    limits = {"final evaluation": preset.final_episodes, "re-score": rescore_episodes}
    for purpose, n in limits.items():
        if n > PER_SEED_BLOCK:
            raise SystemExit(f"{purpose}: {n} episodes per run, at most {PER_SEED_BLOCK} (its seed range per seed)")
    n_fresh = preset.steps // preset.eval_every * preset.eval_episodes
    if preset.periodic_eval == "fresh" and max(seeds, default=0) + n_fresh > PERIODIC_FRESH_BLOCK:
        raise SystemExit(f"fresh periodic evaluations: {n_fresh} episodes per run from seed {max(seeds)} on run "
                         f"past their range of {PERIODIC_FRESH_BLOCK} per seed; evaluate less often")
    if preset.demos_per_seed and ATTEMPTS_PER_EPISODE * preset.demos > DEMO_SEED_STRIDE:
        raise SystemExit(f"demos_per_seed: {preset.demos} demos may try {ATTEMPTS_PER_EPISODE * preset.demos} "
                         f"reset seeds, more than the {DEMO_SEED_STRIDE} between two training seeds' demos")
    ranges = [(k, r) for k in seeds for r in run_seed_ranges(preset, k, rescore_episodes)]
    for k, r in ranges:
        if r.purpose == "demos" and not (DEMO_SEED <= r.start and r.stop <= DEMO_SEED_END):
            raise SystemExit(
                f"the demos of seed {k} may use reset seeds {r.start} to {r.stop - 1}; keep them in "
                f"[{DEMO_SEED}, {DEMO_SEED_END}), clear of the evaluation and held-out seeds "
                f"(e.g. --demo-seed {DEMO_SEED + 1000})")
    for i, (k, a) in enumerate(ranges):
        for j, b in ranges[i + 1:]:
            same = a.purpose == b.purpose
            if (same and (k == j or a.purpose.startswith("periodic evaluations (fixed)")
                          or a.purpose == "held-out demos" or (a.purpose == "demos" and not preset.demos_per_seed))):
                continue  # one range, or shared by design
            if a.overlaps(b):
                raise SystemExit(f"reset seeds overlap: {a.purpose} of seed {k} [{a.start}, {a.stop}) and "
                                 f"{b.purpose} of seed {j} [{b.start}, {b.stop}); change --demo-seed, the "
                                 "number of episodes, or the seeds")

