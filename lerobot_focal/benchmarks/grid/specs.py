"""What a grid runs: one ``RunSpec`` per (task, method, seed), where its files live, and the grid a results
directory's ``grid.json`` records, rebuilt as the runs it names.

The driver builds specs from the command line; every tool that revisits a finished grid (rescore, variant_eval,
expert_gap, tau_profile) rebuilds them from ``grid.json`` with the very preset recorded there
(``GridPreset.from_dict``), so both see the same run folders and data.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from .demos import TaskData, task_data
from .grid_presets import GridPreset, capped_seeds
from .methods import METHODS
from .results import run_key


@dataclass(frozen=True)
class RunSpec:
    task: str
    method: str
    seed: int
    preset: GridPreset
    data: TaskData
    work: Path
    # Step checkpoints from this step on survive the run (``grid --keep-checkpoints-from``); None: only the last.
    # Not part of the preset: keeping files changes no result.
    keep_checkpoints_from: int | None = None

    @property
    def key(self) -> str:
        return run_key(self.task, self.method, self.seed)

    @property
    def run_dir(self) -> Path:
        return self.work / "runs" / self.preset.runs_folder / self.task / self.method / f"seed{self.seed}"

    @property
    def obs_type(self) -> str:
        return METHODS[self.method].obs_type_for(self.preset)


def checkpoint_of(run_dir: Path) -> Path:
    """The final checkpoint a grid run's training wrote (LeRobot's ``checkpoints/last`` link)."""
    return run_dir / "train" / "checkpoints" / "last" / "pretrained_model"


def make_specs(preset: GridPreset, tasks: Sequence[str], phases: Sequence[Sequence[str]], seeds: Sequence[int],
               work: Path) -> list[RunSpec]:
    """Every run of a grid, phase-major, then seed-major: a cut-short grid has whole phases, and within one
    whole seeds. A method the preset caps (``seed_caps``) runs on the first of the seeds only; one with its own
    step budget (``method_steps``) gets it in its run's preset."""
    return [RunSpec(t, m, s, preset.for_method(m), task_data(work, t, preset, METHODS[m].obs_type, s), work)
            for phase in phases for s in seeds for t in tasks for m in phase
            if s in capped_seeds(preset.seed_caps, m, seeds)]


def specs_of_grid(out: Path, work: Path) -> dict[str, RunSpec]:
    """The runs of the grid whose ``grid.json`` is in ``out``, by run key, with the preset (overrides included)
    it records: what tools that revisit a finished grid's runs start from."""
    grid = json.loads((out / "grid.json").read_text())
    phases = grid.get("phases", [grid["methods"]])
    specs = make_specs(GridPreset.from_dict(grid["preset"]), grid["tasks"], phases, grid["seeds"], Path(work).resolve())
    return {s.key: s for s in specs}
