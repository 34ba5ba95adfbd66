"""The grid's results file: one JSON line per finished (or failed) run, appended as each run ends, and the record
each line holds (``RunRecord``: the one place that names a run's measured fields).

Appending whole lines under an exclusive lock means an interrupted grid leaves every finished run on disk and
at most a torn last line, which is skipped on reading; the next invocation runs only what has no ``ok`` record.
"""

from __future__ import annotations

import fcntl
import json
import logging
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

#: Metadata of the fields the report derives from the stored ones; never written to results.jsonl.
DERIVED = {"derived": True}


@dataclass
class RunRecord:
    """One run of the grid, as ``results.jsonl`` stores it. Success rates are fractions in [0, 1].

    A field a record lacks reads as its default here: records written before the field existed (no
    ``periodic_eval`` meant "fixed") and failed runs (which hold only the identity, ``attempts`` and ``error``).
    Fields that are None (or empty lists) are not written. Keys of a file that are no field (another tool's, a
    later version's) are kept in ``extra`` and written back, so reading and rewriting a file loses nothing; the
    grid itself builds records with the constructor, which refuses an unknown name.
    """

    key: str  # task|method|seed
    status: str  # "ok" or "failed"
    task: str | None = None  # None: read from the key
    method: str | None = None
    seed: int | None = None
    preset: str | None = None
    finished_at: str | None = None
    started_at: str | None = None
    # Periodic evaluations inside lerobot-train
    success_top_k: float | None = None  # mean of the top-k evaluations
    periodic_eval: str = "fixed"  # "fresh": success_top_k is the paper's estimator (DP3's runner)
    success_final: float | None = None  # the last evaluation
    atv: float | None = None  # executed actions of the last evaluation
    curve: list[dict] = field(default_factory=list)  # per evaluation: step, success, atv, length
    # The final checkpoint on fresh episodes (the preset's final_episodes; absent when 0)
    success_fresh: float | None = None
    atv_fresh: float | None = None
    fresh_episodes: int | None = None
    final_eval_s: float | None = None
    # The final checkpoint's analysis (analyze.py): held-out open-loop metrics, cost per chunk
    compounding_error: float | None = None
    compounding_curve: list[float] = field(default_factory=list)
    ts_score: float | None = None
    heldout_action_rmse: float | None = None
    nfe: float | None = None
    latency_ms: float | None = None
    n_params: int | None = None
    heldout_episodes: int | None = None
    # Cost and provenance
    update_s_per_step: float | None = None
    torch_threads: int | None = None  # the run's OMP_NUM_THREADS (None: the library's default)
    wall_s: float | None = None  # training and periodic evaluations, over every resumed segment
    run_dir: str | None = None
    resumed_from_steps: list[int] | None = None  # a run resumed from checkpoints: the steps, the work lost
    lost_s: float | None = None
    spans: list[list[str]] | None = None  # (start, end) of each segment, what the report's wall time counts
    # A failed run
    attempts: int | None = None
    error: str | None = None
    # Derived by the report from the fields above and rescore.json (see report.with_estimators)
    success_top_k_paper: float | None = field(default=None, metadata=DERIVED)
    success_top_k_fixed: float | None = field(default=None, metadata=DERIVED)
    success_rescore_mean: float | None = field(default=None, metadata=DERIVED)
    extra: dict[str, Any] = field(default_factory=dict, metadata=DERIVED)  # keys that are no field, as read

    def __post_init__(self) -> None:
        task, method, seed = (self.key.split("|") + [None, None, None])[:3]
        self.task = self.task if self.task is not None else task
        self.method = self.method if self.method is not None else method
        if self.seed is None and seed is not None:
            self.seed = int(seed)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunRecord:
        names = {f.name for f in fields(cls) if not f.metadata.get("derived")}
        known = {k: v for k, v in data.items() if k in names}
        return cls(**known, extra={k: v for k, v in data.items() if k not in names})

    def to_dict(self) -> dict[str, Any]:
        derived = {f.name for f in fields(self) if f.metadata.get("derived")}
        stored = {k: v for k, v in asdict(self).items() if v is not None and v != [] and k not in derived}
        return {**stored, **self.extra}

    def value(self, name: str) -> float:
        """A numeric field by name, NaN where the run did not measure it (for means over runs)."""
        v = getattr(self, name)
        return math.nan if v is None else float(v)


def run_key(task: str, method: str, seed: int) -> str:
    return f"{task}|{method}|{seed}"


class ResultsFile:
    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def records(self) -> list[RunRecord]:
        if not self.path.exists():
            return []
        out = []
        for n, line in enumerate(self.path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                out.append(RunRecord.from_dict(json.loads(line)))
            except json.JSONDecodeError:
                logging.warning("%s:%d: skipping an unreadable (torn) line", self.path, n)
        return out

    def ok(self) -> dict[str, RunRecord]:
        """The latest successful record of each run key."""
        return {r.key: r for r in self.records() if r.status == "ok"}

    def append(self, record: RunRecord | dict[str, Any]) -> None:
        """Append one record (a dict as another tool wrote it: its keys that are no field are kept)."""
        if isinstance(record, dict):
            record = RunRecord.from_dict(record)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        line = json.dumps(record.to_dict()) + "\n"
        with open(self.path, "a+b") as f:
            fcntl.flock(f, fcntl.LOCK_EX)
            try:
                if f.seek(0, 2) > 0:
                    f.seek(-1, 2)
                    if f.read(1) != b"\n":  # a torn line from an interrupted write: keep ours separate
                        line = "\n" + line
                f.write(line.encode())
                f.flush()
            finally:
                fcntl.flock(f, fcntl.LOCK_UN)
