"""Crash-safe episode-by-episode writing of a LeRobotDataset folder: commit after each episode, roll back on start.

LeRobot's writer keeps each parquet file open across episodes and writes its footer only when the file is
closed, so a process killed with SIGKILL (or a power cut) leaves files no reader can open, and
`LeRobotDataset.resume` then fails ("Parquet magic bytes not found in footer"): every episode is lost.

The writer that uses this module closes the dataset after every saved episode (`finalize`) and resumes it for
the next one; LeRobot then starts new data and episode-metadata files, so a file, once closed, never changes.
:func:`commit` then records the folder's state: the list of closed files under ``data/`` and
``meta/episodes/`` and a copy of the small files LeRobot rewrites in place (``meta/info.json``,
``meta/stats.json``, ``meta/tasks.parquet``). :func:`rollback`, run before the dataset is reopened, returns
the folder to its last commit: files written after it (the episode that was being saved when the process
died) are removed, the rewritten files are restored, and temporary frame images are cleared. So a kill loses
at most the episode in flight, and a rerun continues from the last finished one.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

COMMIT_DIR = ".focal_commit"
_MANIFEST = "manifest.json"
_REWRITTEN = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet")
_APPEND_ONLY = ("data", "meta/episodes")
_TEMPORARY = ("images",)  # frame images waiting to be embedded into parquet; finished episodes hold theirs


def _files(root: Path) -> list[str]:
    out = []
    for top in _APPEND_ONLY:
        base = root / top
        if base.is_dir():
            out += [str(p.relative_to(root)) for p in base.rglob("*") if p.is_file()]
    return sorted(out)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def commit(root: str | Path) -> None:
    """Record `root` as it is now (call only when the dataset is finalized: every file closed)."""
    root = Path(root)
    log = root / COMMIT_DIR
    staging = root / (COMMIT_DIR + ".tmp")
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "files").mkdir(parents=True)
    for rel in _REWRITTEN:
        if (root / rel).is_file():
            dst = staging / "files" / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(root / rel, dst)
    previous = set(json.loads((log / _MANIFEST).read_text())["files"]) if (log / _MANIFEST).is_file() else set()
    for rel in _files(root):  # new closed files must be on disk before the commit that lists them
        if rel not in previous:
            with open(root / rel, "rb") as f:
                os.fsync(f.fileno())
    manifest = {"files": _files(root), "rewritten": [r for r in _REWRITTEN if (root / r).is_file()]}
    (staging / _MANIFEST).write_text(json.dumps(manifest, indent=1))
    for path in (staging / "files").rglob("*"):
        if path.is_file():
            with open(path, "rb") as f:
                os.fsync(f.fileno())
    # Swap in the new commit: at every moment one complete commit exists (the old one until the rename).
    old = root / (COMMIT_DIR + ".old")
    shutil.rmtree(old, ignore_errors=True)
    if log.exists():
        log.rename(old)
    staging.rename(log)
    _fsync_dir(root)
    shutil.rmtree(old, ignore_errors=True)


def _recover_interrupted_swap(root: Path) -> None:
    log, old = root / COMMIT_DIR, root / (COMMIT_DIR + ".old")
    if not log.exists() and old.exists():
        old.rename(log)  # killed between the two renames of commit(): the old commit is the valid one
    shutil.rmtree(root / (COMMIT_DIR + ".tmp"), ignore_errors=True)


def has_commit(root: str | Path) -> bool:
    root = Path(root)
    _recover_interrupted_swap(root)
    return (root / COMMIT_DIR / _MANIFEST).is_file()


def rollback(root: str | Path) -> list[str]:
    """Return `root` to its last commit; returns the paths it removed or restored (empty when it was intact)."""
    root = Path(root)
    if not has_commit(root):
        return []
    log = root / COMMIT_DIR
    manifest = json.loads((log / _MANIFEST).read_text())
    committed = set(manifest["files"])
    missing = sorted(committed - set(_files(root)))
    if missing:
        raise RuntimeError(
            f"{root} lost files of finished episodes since its last commit: {missing[:5]}. They were removed by "
            "something other than this tool; restore them from a backup, or start a new dataset folder."
        )
    changed = [rel for rel in _files(root) if rel not in committed]
    for rel in changed:
        (root / rel).unlink()
    for rel in manifest["rewritten"]:
        saved = log / "files" / rel
        if not (root / rel).is_file() or (root / rel).read_bytes() != saved.read_bytes():
            shutil.copy2(saved, root / rel)
            changed.append(rel)
    for rel in _REWRITTEN:
        if rel not in manifest["rewritten"] and (root / rel).is_file():
            (root / rel).unlink()  # written after the commit (e.g. the first episode's stats)
            changed.append(rel)
    for rel in _TEMPORARY:
        if (root / rel).exists():
            shutil.rmtree(root / rel)
            changed.append(rel + "/")
    return changed

