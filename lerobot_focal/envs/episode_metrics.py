"""Per-episode metrics the focal envs record: success, length and Action Total Variation (the paper's ATV)."""

from __future__ import annotations


def action_total_variation(actions) -> float:
    """ATV = 1/((L-1) d) * sum_t sum_j |a_{t+1}^j - a_t^j| over one episode's executed (L, d) actions."""
    import numpy as np

    a = np.asarray(actions, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] < 2:
        return 0.0
    return float(np.abs(np.diff(a, axis=0)).sum() / ((a.shape[0] - 1) * a.shape[1]))


class EpisodeMetrics:
    """Per-episode record of executed actions -> success, length and Action Total Variation.

    The env calls ``step`` with each executed action and ``finish`` at termination/truncation; finished
    episodes are logged (``logging.info``, visible in ``lerobot-eval``'s output) and, when ``path`` is set,
    appended as one JSON line each to that file (the summary table for ``lerobot-eval`` runs, which keep
    only success and reward themselves).
    """

    def __init__(self, task: str, path: str | None = None) -> None:
        self.task = task
        self.path = path
        self.actions: list = []
        self.seed: int | None = None
        self.finished: list[dict] = []

    def start(self, seed: int | None) -> None:
        self.actions = []
        self.seed = seed

    def step(self, action) -> None:
        import numpy as np

        self.actions.append(np.array(action, dtype=np.float32, copy=True))

    def finish(self, is_success: bool) -> dict:
        import json
        import logging
        import time

        record = {
            "task": self.task,
            "seed": self.seed,
            "success": bool(is_success),
            "length": len(self.actions),
            "action_total_variation": action_total_variation(self.actions),
            # Wall-clock end (Unix seconds): when an interrupted grid run resumes, it says how long the kept
            # part of the run took.
            "ended_at": round(time.time(), 3),
        }
        self.finished.append(record)
        logging.info(
            "focal env episode: task=%s seed=%s success=%s length=%d ATV=%.5f",
            record["task"], record["seed"], record["success"], record["length"], record["action_total_variation"],
        )
        if self.path:
            with open(self.path, "a") as f:
                f.write(json.dumps(record) + "\n")
        self.actions = []
        return record
