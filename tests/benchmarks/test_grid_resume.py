"""Which checkpoint an interrupted grid run continues from, and what is dropped (files only; the real resume of a
`lerobot-train` process is in test_grid_runs.py)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from lerobot_focal.benchmarks.grid.resume import (
    checkpoints,
    earlier_segments,
    find_resume_point,
    prepare_resume,
    prune_checkpoints,
    read_segments,
    start_segment,
)

CMD = ["lerobot-train", "--steps=8"]
START = time.time() - 600.0


def _run_dir(tmp_path: Path, ckpt_steps: list[int], evals_done: int, torn: bool = False) -> Path:
    """A run that evaluates 2 episodes every 2 steps: `evals_done` complete evaluations (each followed by an
    autoreset episode without a seed), then half of the next one."""
    run = tmp_path / "run"
    for step in ckpt_steps:
        state = run / "train" / "checkpoints" / f"{step:06d}" / "training_state"
        state.mkdir(parents=True)
        (state / "training_step.json").write_text(json.dumps({"step": step}))
    (run / "train" / "checkpoints" / "last").symlink_to(f"{max(ckpt_steps):06d}")
    start_segment(run, CMD, 0)
    segments = read_segments(run)
    segments[0]["start_s"] = START  # as if training had started at START, each episode ending 1 s after the last
    (run / "segments.json").write_text(json.dumps(segments))
    lines, t = [], START
    for e in range(evals_done):
        for k in range(2):
            t += 1
            lines.append({"seed": k, "success": e % 2 == 0, "ended_at": t})
        lines.append({"seed": None, "success": False})
    lines.append({"seed": 0, "success": True, "ended_at": t + 50})  # the evaluation that was cut short
    text = "".join(json.dumps(x) + "\n" for x in lines) + ('{"seed": 1, "succ' if torn else "")
    (run / "eval_episodes.jsonl").write_text(text)
    return run


def test_resumes_from_the_newest_checkpoint_whose_evaluation_completed(tmp_path):
    # Checkpoints at 2, 4, 6; evaluations at 2 and 4 complete, the one at 6 cut short: resume from 4.
    run = _run_dir(tmp_path, [2, 4, 6], evals_done=2, torn=True)
    point = find_resume_point(run, CMD, eval_every=2, episodes_per_eval=2)
    assert point is not None and point.step == 4 and point.episodes_kept == 4
    assert point.kept_until == START + 4  # the end of the last kept episode, as the env recorded it
    assert point.config_path == run / "train" / "checkpoints" / "000004" / "pretrained_model" / "train_config.json"

    prepare_resume(run, point)
    kept = [json.loads(x) for x in (run / "eval_episodes.jsonl").read_text().splitlines()]
    assert [e["seed"] for e in kept] == [0, 1, None, 0, 1]  # the cut evaluation and the torn line are gone
    assert sorted(checkpoints(run)) == [2, 4]  # the checkpoint after the resume point is deleted
    assert (run / "train" / "checkpoints" / "last").resolve().name == "000004"
    (segment,) = read_segments(run)
    assert segment["kept_step"] == 4 and segment["lost_s"] > 500  # the files were written ~600 s after START

    start_segment(run, CMD, 4)
    kept_s, spans, lost_s, resumed = earlier_segments(run)
    assert resumed == [4] and len(spans) == 1 and lost_s == segment["lost_s"]
    assert kept_s == 4.0

    # Interrupted again before its next evaluation: the same point; that second segment kept nothing.
    again = find_resume_point(run, CMD, eval_every=2, episodes_per_eval=2)
    assert again.step == 4
    prepare_resume(run, again)
    start_segment(run, CMD, 4)
    kept_s2, spans2, lost_s2, resumed2 = earlier_segments(run)
    assert resumed2 == [4, 4] and kept_s2 == kept_s and spans2 == spans and lost_s2 >= lost_s


def test_starts_over_without_a_usable_checkpoint_or_with_another_command(tmp_path):
    run = _run_dir(tmp_path, [2, 4], evals_done=1)
    assert find_resume_point(run, CMD, 2, 2).step == 2
    assert find_resume_point(run, [*CMD, "--policy.ablation=wo_las"], 2, 2) is None  # the method changed
    # The only checkpoint's evaluation never completed: nothing to continue from.
    assert find_resume_point(_run_dir(tmp_path / "b", [2], evals_done=0), CMD, 2, 2) is None
    # A checkpoint whose training state was not written (interrupted while saving) is not used.
    run_c = _run_dir(tmp_path / "c", [2, 4], evals_done=2)
    (run_c / "train" / "checkpoints" / "000004" / "training_state" / "training_step.json").unlink()
    assert find_resume_point(run_c, CMD, 2, 2).step == 2
    (run_c / "segments.json").unlink()  # started by an older grid: no record of its command
    assert find_resume_point(run_c, CMD, 2, 2) is None


def test_pruning_keeps_the_newest_checkpoints(tmp_path):
    run = _run_dir(tmp_path, [2, 4, 6, 8], evals_done=4)
    prune_checkpoints(run, keep=2)
    assert sorted(checkpoints(run)) == [6, 8]
    prune_checkpoints(run, keep=1)
    assert sorted(checkpoints(run)) == [8] and (run / "train" / "checkpoints" / "last").resolve().name == "000008"


def test_pruning_spares_the_checkpoints_asked_for_from_a_step_on(tmp_path):
    """`grid --keep-checkpoints-from 4` keeps steps 4, 6 and 8 for checkpoint-eval, and still drops step 2."""
    run = _run_dir(tmp_path, [2, 4, 6, 8], evals_done=4)
    prune_checkpoints(run, keep=1, keep_from=4)
    assert sorted(checkpoints(run)) == [4, 6, 8]


@pytest.mark.subprocess
def test_housekeeping_runs_beside_the_child_and_its_errors_do_not_stop_it(tmp_path):
    import sys

    from lerobot_focal.benchmarks.grid.processes import run_logged

    calls = []

    def poll() -> None:
        calls.append(1)
        raise ValueError("a housekeeping bug")

    run_logged([sys.executable, "-c", "import time; time.sleep(1.0); print('done')"], tmp_path / "child.log",
               {}, "child", poll=poll, poll_every_s=0.1)
    assert len(calls) >= 3 and "done" in (tmp_path / "child.log").read_text()
