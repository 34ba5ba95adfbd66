"""Continue an interrupted grid run from its newest usable checkpoint instead of starting it over.

Why: a run on point clouds takes about an hour on a CPU, and one of the paper preset many hours on a GPU; a
Ctrl-C, a crash or the end of a working session used to throw all of it away.

How: a run saves a LeRobot checkpoint at every periodic evaluation (``--save_freq`` = ``eval_every``), and
LeRobot saves it just before that evaluation. The next grid invocation continues the run with LeRobot's own
``lerobot-train --config_path=<checkpoint>/pretrained_model/train_config.json --resume=true`` from the newest
checkpoint whose evaluation completed: LeRobot restores the weights (focal's EMA/target network and its step
counter included), the optimizer, the scheduler, the RNG state and the position in the data order. Evaluations
after that checkpoint are dropped from ``eval_episodes.jsonl`` and run again by the resumed training.

A resumed run is not bit-identical to an uninterrupted one: the evaluation at the resume step draws policy noise
from the global RNG after the checkpoint saved it, so the training noise after the resume differs, as with
another noise seed. A run resumes only with the training command it started with (``segments.json``); after
any change to the method's or preset's arguments it starts over.

While a run trains only its two newest checkpoints are kept (the newest one's evaluation may not have
completed), and only the final one once it ends: the paper preset's checkpoints are gigabytes each.
``grid --keep-checkpoints-from STEP`` keeps every checkpoint from that step on as well, for
``lerobot-focal-bench checkpoint-eval`` (late checkpoints on the same fresh episodes).
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

SEGMENTS_FILE = "segments.json"
EPISODES_FILE = "eval_episodes.jsonl"


def iso(t: float) -> str:
    return datetime.fromtimestamp(t).strftime("%Y-%m-%dT%H:%M:%S")


def checkpoints(run_dir: Path) -> dict[int, Path]:
    """The run's step checkpoints (LeRobot's ``train/checkpoints/<step>`` folders) by step."""
    root = run_dir / "train" / "checkpoints"
    if not root.is_dir():
        return {}
    return {int(d.name): d for d in root.iterdir() if d.name.isdigit() and not d.is_symlink()}


def prune_checkpoints(run_dir: Path, keep: int, keep_from: int | None = None) -> None:
    """Delete all but the ``keep`` newest step checkpoints (safe while LeRobot writes the newest one), and
    those from step ``keep_from`` on (``grid --keep-checkpoints-from``: for ``checkpoint-eval``)."""
    found = checkpoints(run_dir)
    for step in sorted(found)[:-keep]:
        if keep_from is None or step < keep_from:
            shutil.rmtree(found[step], ignore_errors=True)


def read_segments(run_dir: Path) -> list[dict]:
    """The run's training segments: one per start of `lerobot-train` (the first, then each resume)."""
    path = run_dir / SEGMENTS_FILE
    return json.loads(path.read_text()) if path.exists() else []


def start_segment(run_dir: Path, command: list[str], from_step: int) -> None:
    now = time.time()
    segments = read_segments(run_dir) + [{"command": command, "from_step": from_step, "started_at": iso(now),
                                          "start_s": now}]
    (run_dir / SEGMENTS_FILE).write_text(json.dumps(segments, indent=1))


def forget_resume(run_dir: Path) -> None:
    """Make the run start over next time (its resume failed, so resuming again would fail the same way)."""
    (run_dir / SEGMENTS_FILE).unlink(missing_ok=True)


def _episode_lines(path: Path) -> list[tuple[str, dict]]:
    """(line, record) of every whole line; a line torn by the interruption is dropped."""
    out = []
    for line in path.read_text().splitlines() if path.exists() else []:
        try:
            out.append((line, json.loads(line)))
        except json.JSONDecodeError:
            continue
    return out


def seeded_records(path: Path) -> list[dict]:
    """An evaluation's episode records (the env's ``metrics_path`` file), autoreset episodes, which carry no
    seed, left out."""
    return [rec for _, rec in _episode_lines(path) if rec.get("seed") is not None]


def seeded_episodes(run_dir: Path) -> list[dict]:
    """The run's periodic-evaluation episodes so far."""
    return seeded_records(run_dir / EPISODES_FILE)


@dataclass(frozen=True)
class ResumePoint:
    step: int  # the checkpoint's training step; the evaluations up to and including it are kept
    checkpoint: Path
    episodes_kept: int  # seeded evaluation episodes up to that step
    kept_until: float  # when the kept evaluations ended (Unix seconds)

    @property
    def config_path(self) -> Path:
        return self.checkpoint / "pretrained_model" / "train_config.json"


def find_resume_point(run_dir: Path, command: list[str], eval_every: int, episodes_per_eval: int) -> ResumePoint | None:
    """The newest checkpoint of an interrupted run whose evaluation completed, or None to start the run over
    (nothing usable, or the run was started with another training command)."""
    segments = read_segments(run_dir)
    if not segments or segments[0]["command"] != command:
        return None
    seeded = seeded_episodes(run_dir)
    completed_step = len(seeded) // episodes_per_eval * eval_every
    found = checkpoints(run_dir)
    usable = [s for s, path in found.items() if 0 < s <= completed_step and s % eval_every == 0
              and (path / "training_state" / "training_step.json").exists()]
    if not usable:
        return None
    step = max(usable)
    kept = step // eval_every * episodes_per_eval
    ended = seeded[kept - 1].get("ended_at")  # recorded by the env; older records: the checkpoint's time
    return ResumePoint(step, found[step], kept, float(ended) if ended else found[step].stat().st_mtime)


def prepare_resume(run_dir: Path, point: ResumePoint) -> None:
    """Drop what came after ``point`` (later evaluation episodes and checkpoints) and note in the last segment
    how much of it was kept and how much time the interruption lost."""
    lost_until = max((p.stat().st_mtime for p in run_dir.rglob("*") if p.is_file()), default=point.kept_until)
    keep, seeded = [], 0
    for line, rec in _episode_lines(run_dir / EPISODES_FILE):
        if seeded == point.episodes_kept:
            break
        keep.append(line)
        seeded += rec.get("seed") is not None
    (run_dir / EPISODES_FILE).write_text("".join(f"{line}\n" for line in keep))
    for step, path in checkpoints(run_dir).items():
        if step > point.step:
            shutil.rmtree(path)
    last = run_dir / "train" / "checkpoints" / "last"
    if last.is_symlink():
        last.unlink()
    last.symlink_to(point.checkpoint.name)  # relative, as LeRobot writes it
    segments = read_segments(run_dir)
    # A segment interrupted before its first evaluation kept nothing: its kept span ends where it started.
    kept_until = max(point.kept_until, segments[-1]["start_s"])
    segments[-1].update(kept_step=point.step, kept_until_s=kept_until, lost_s=max(0.0, lost_until - kept_until))
    (run_dir / SEGMENTS_FILE).write_text(json.dumps(segments, indent=1))


def resume_command(lerobot_train: str, point: ResumePoint) -> list[str]:
    """LeRobot's own resume: the checkpoint's saved training configuration, continued."""
    return [lerobot_train, f"--config_path={point.config_path}", "--resume=true"]


def earlier_segments(run_dir: Path) -> tuple[float, list[list[str]], float, list[int]]:
    """What the interrupted segments before the current one contributed: (kept training seconds, their
    [start, end] spans as ISO times, seconds lost to interruptions, steps resumed from)."""
    kept_s, spans, lost_s, resumed = 0.0, [], 0.0, []
    for seg in read_segments(run_dir)[:-1]:
        kept_s += seg["kept_until_s"] - seg["start_s"]
        if seg["kept_until_s"] > seg["start_s"]:
            spans.append([seg["started_at"], iso(seg["kept_until_s"])])
        lost_s += seg["lost_s"]
        resumed.append(seg["kept_step"])
    return kept_s, spans, lost_s, resumed
