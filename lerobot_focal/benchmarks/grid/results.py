"""The grid's results file: one JSON line per finished (or failed) run, appended as each run ends.

Appending whole lines under an exclusive lock means an interrupted grid leaves every finished run on disk and
at most a torn last line, which is skipped on reading; the next invocation runs only what has no ``ok`` record.
"""

from __future__ import annotations

import fcntl
import json
import logging
from pathlib import Path


def run_key(task: str, method: str, seed: int) -> str:
    return f"{task}|{method}|{seed}"


class ResultsFile:
    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def records(self) -> list[dict]:
        if not self.path.exists():
            return []
        out = []
        for n, line in enumerate(self.path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                logging.warning("%s:%d: skipping an unreadable (torn) line", self.path, n)
        return out

    def ok(self) -> dict[str, dict]:
        """The latest successful record of each run key."""
        return {r["key"]: r for r in self.records() if r.get("status") == "ok"}

    def append(self, record: dict) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        line = json.dumps(record) + "\n"
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
