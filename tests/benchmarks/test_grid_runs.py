"""The grid for real, at toy scale: scripted-expert datasets, `lerobot-train` processes with LeRobot's periodic
evaluation in `focal_metaworld`, checkpoint analysis, the resumable results file, and a real local Ray instance."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lerobot_focal.benchmarks.grid import driver
from lerobot_focal.benchmarks.grid.demos import ensure_task_data
from lerobot_focal.benchmarks.grid.grid_presets import PRESETS
from lerobot_focal.benchmarks.grid.results import ResultsFile
from lerobot_focal.benchmarks.grid.run import RunSpec

pytestmark = pytest.mark.subprocess  # grid runs: lerobot-train and lerobot-eval processes

TINY = dict(steps=4, eval_every=2, eval_episodes=2, demos=2, heldout_demos=1, episode_length=100, batch_size=8)
TINY_ARGS = ["--steps", "4", "--eval-every", "2", "--eval-episodes", "2", "--demos", "2", "--heldout-demos", "1",
             "--episode-length", "100", "--batch-size", "8", "--tasks", "reach", "--seeds", "0"]


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("bench_work")
    ensure_task_data(work, "reach", PRESETS["cpu"].with_overrides(**TINY))
    return work


def test_local_grid_runs_reports_and_resumes(work, tmp_path, capsys):
    out = tmp_path / "out"
    assert driver.main([*TINY_ARGS, "--methods", "focal", "--out", str(out), "--work", str(work)]) == 0
    (record,) = ResultsFile(out / "results.jsonl").records()
    assert record.status == "ok" and record.key == "reach|focal|0"
    assert [c["step"] for c in record.curve] == [2, 4]  # LeRobot evaluated at steps 2 and 4
    assert 0.0 <= record.success_top_k <= 1.0 and record.atv > 0
    assert record.nfe == 1.0  # one U-Net evaluation per executed chunk, counted by hooks
    assert record.latency_ms > 0 and len(record.compounding_curve) >= 20  # held-out reach: ~50 steps
    report = (out / "report.md").read_text()
    assert "FocalPolicy" in report and "top-5" in report
    for png in ("learning_curves.png", "success_bars.png", "compounding_error.png"):
        assert (out / png).stat().st_size > 5000

    # A second invocation finds the run done and starts nothing.
    capsys.readouterr()
    assert driver.main([*TINY_ARGS, "--methods", "focal", "--out", str(out), "--work", str(work)]) == 0
    assert "1 already in" in capsys.readouterr().out
    assert len(ResultsFile(out / "results.jsonl").records()) == 1
    starts = (work / "attempts.log").read_text().splitlines()
    assert sum("reach|focal|0" in line for line in starts) == 1

    # The finished run's checkpoint, rolled out by LeRobot's rollout with the scripted expert asked at every state.
    from lerobot_focal.benchmarks.grid.diagnostics import expert_gap

    run_dir = next((work / "runs").rglob("reach/focal/seed0"))
    grid_episodes = (run_dir / "eval_episodes.jsonl").read_text()
    assert expert_gap.main(["--out", str(out), "--work", str(work), "--episodes", "2"]) == 0
    gap = json.loads((out / "expert_gap.json").read_text())["reach|focal|0"]
    assert gap["episodes"] == 2 and 0 <= gap["successes"] <= 2
    rows = gap["windows"]["success"] + gap["windows"]["failure"]
    assert rows and all(len(r["gap"]) == 4 and all(0.0 <= g <= 2.0 for g in r["gap"]) for r in rows)
    assert sum(r["episodes"] for r in rows if r["start"] == 0) == 2  # every episode has a first window
    own = [json.loads(line) for line in (run_dir / "expert_gap_episodes.jsonl").read_text().splitlines()]
    assert sorted(e["seed"] for e in own) == [expert_gap.EXPERT_GAP_SEED, expert_gap.EXPERT_GAP_SEED + 1]
    assert (run_dir / "eval_episodes.jsonl").read_text() == grid_episodes  # the run's own files are untouched
    split = gap["placement"]  # each start against the demos' range of observation.environment_state
    assert split["inside"][1] + split["outside"][1] == 2
    assert split["inside"][0] + split["outside"][0] == gap["successes"]
    dither = gap["dither"]  # focal re-plans every n_action_steps; each present row has the four dimensions
    assert dither["replan_every"] >= 1 and (dither["success"] or dither["failure"])
    assert all(len(v) == 4 and all(0.0 <= x <= 2.0 for x in v)
               for name in ("success", "failure") for v in dither[name].values())
    md = (out / "expert_gap.md").read_text()
    assert (out / "expert_gap.png").stat().st_size > 5000 and "reach · focal · 0" in md and "| reach · focal | " in md
    assert "## Dither" in md and f"| reach · focal · 0 | {dither['replan_every']} |" in md
    capsys.readouterr()
    assert expert_gap.main(["--out", str(out), "--work", str(work), "--episodes", "2"]) == 0
    assert "reach|focal|0:" not in capsys.readouterr().out  # measured already: skipped, no progress line
    assert expert_gap.main(["--out", str(out), "--work", str(work), "--methods", "diffusion"]) == 2

    # The same checkpoint's one-step map measured along the flow, on the run's demos and held-out episodes.
    from lerobot_focal.benchmarks.grid.diagnostics import tau_profile

    assert tau_profile.main(["--out", str(out), "--work", str(work), "--frames", "16"]) == 0
    prof = json.loads((out / "tau_profile.json").read_text())["reach|focal|0"]
    for split in ("train", "heldout"):
        p = prof[split]
        assert p["taus"][0] == 0.01 and p["taus"][-1] == 0.99  # first: the policy's own inference point anchor.eps
        assert 0 < p["frames"] <= 16 and len(p["proximal"]) == len(p["macro"]) == len(p["taus"])
        assert all(x >= 0 for x in p["proximal"] + p["macro"]) and p["reference"]["macro"] > 0
        assert p["proximal"][-1] < p["proximal"][0]  # f(M_0.99) is within (1 − τ)·|v − u| of the data
    assert (out / "tau_profile.png").stat().st_size > 5000
    assert "| reach · focal |" in (out / "tau_profile.md").read_text()
    capsys.readouterr()
    assert tau_profile.main(["--out", str(out), "--work", str(work), "--frames", "16"]) == 0
    assert "reach|focal|0:" not in capsys.readouterr().out  # measured already: skipped
    assert tau_profile.main(["--out", str(out), "--work", str(work), "--methods", "wo_las"]) == 2


@pytest.mark.slow  # ~2 min: a grid run and three evaluations; the default suite keeps checkpoint-eval's units
def test_kept_checkpoints_are_evaluated_on_the_final_evaluations_own_episodes(work, tmp_path, capsys):
    """`grid --keep-checkpoints-from 2` keeps step 2's checkpoint; checkpoint-eval scores it on the very
    placements and policy noise of the grid's final evaluation, which an evaluation of the final checkpoint under
    checkpoint-eval's own file names reproduces exactly (so differences between steps are the checkpoints')."""
    from lerobot_focal.benchmarks.grid.diagnostics import checkpoint_eval
    from lerobot_focal.benchmarks.grid.resume import checkpoints
    from lerobot_focal.benchmarks.grid.specs import specs_of_grid

    out = tmp_path / "out"
    args = [*TINY_ARGS, "--methods", "focal", "--final-episodes", "2", "--out", str(out), "--work", str(work)]
    assert driver.main([*args, "--keep-checkpoints-from", "2"]) == 0
    spec = specs_of_grid(out, work)["reach|focal|0"]
    assert sorted(checkpoints(spec.run_dir)) == [2, 4]  # not pruned to the last one
    assert "keep_checkpoints_from" not in (out / "grid.json").read_text()  # keeping files changes no result

    capsys.readouterr()
    assert checkpoint_eval.main(["--out", str(out), "--work", str(work)]) == 0
    entry = json.loads((out / "checkpoint_eval.json").read_text())["reach|focal|0"]
    assert entry["steps"] == [2, 4] and entry["shared_episodes"] == 2 and entry["periodic_episodes"] == 2
    record = ResultsFile(out / "results.jsonl").records()[0]
    assert entry["periodic_success"] == [c["success"] for c in record.curve]
    assert entry["shared_success"][1] == record.success_fresh  # the final step is the grid's own evaluation
    assert sorted(entry["episodes"]["2"]) == sorted(entry["episodes"]["4"])  # same placements
    assert (out / "checkpoint_eval.png").stat().st_size > 5000
    assert "| same 2 episodes, % |" in (out / "checkpoint_eval.md").read_text()
    assert "[checkpoint_eval](checkpoint_eval.md) (`lerobot-focal-bench checkpoint-eval`)" in (
        out / "report.md").read_text()
    assert "step 2:" in capsys.readouterr().out
    assert checkpoint_eval.main(["--out", str(out), "--work", str(work)]) == 0
    assert "step 2:" not in capsys.readouterr().out  # evaluated already: kept, not run again

    def by_seed(name: str) -> dict:
        eps = [json.loads(x) for x in (spec.run_dir / f"{name}_episodes.jsonl").read_text().splitlines() if x]
        return {e["seed"]: (e["success"], e["action_total_variation"]) for e in eps if e.get("seed") is not None}

    checkpoint_eval.evaluate_checkpoint(spec, 4, checkpoints(spec.run_dir)[4])
    assert by_seed("ckpt4") == by_seed("final")  # same episodes and noise: identical actions, to the last digit


@pytest.mark.slow  # ~1.5 min: Ray, the optional cluster executor; the local executor's tests stay in the default suite
def test_ray_executor_runs_gathers_and_retries(work, tmp_path):
    pytest.importorskip("ray")
    from lerobot_focal.benchmarks.grid.demos import task_data
    from lerobot_focal.benchmarks.grid.executors import run_ray

    preset = PRESETS["cpu"].with_overrides(**TINY)
    good = RunSpec("reach", "diffusion", 0, preset, task_data(work, "reach", preset), work)
    broken = preset.with_overrides(extra_train_args=("--policy.no_such_field=1",))  # lerobot-train refuses it
    bad = RunSpec("reach", "focal", 7, broken, task_data(work, "reach", preset), work)
    results = ResultsFile(tmp_path / "results.jsonl")
    run_ray([good, bad], results.append, retries=1, init_kwargs={"num_cpus": 2, "include_dashboard": False})

    records = {r.key: r for r in results.records()}
    assert records["reach|diffusion|0"].status == "ok"
    assert records["reach|diffusion|0"].nfe == 10.0  # DDIM 10, counted
    assert records["reach|focal|7"].status == "failed"
    assert "lerobot-train exited" in records["reach|focal|7"].error
    starts = (work / "attempts.log").read_text().splitlines()
    assert sum("reach|focal|7" in line for line in starts) == 2  # Ray retried the failed run once
    assert json.loads(results.path.read_text().splitlines()[0])  # whole lines only


def _interrupt_once_training(cmd: list[str], work: Path, keys: list[str]) -> tuple[str, int]:
    """Start the grid driver, wait until every run in `keys` has started and its lerobot-train is up, send
    SIGINT and return (output, return code)."""
    attempts = work / "attempts.log"
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.time() + 300
    run_root = work / "runs" / PRESETS["cpu"].with_overrides(**TINY).runs_folder
    logs = [run_root / task / method / f"seed{seed}" / "train.log"
            for task, method, seed in (key.split("|") for key in keys)]
    while not all(log.exists() for log in logs):
        if time.time() > deadline or proc.poll() is not None:
            proc.kill()
            started = attempts.read_text() if attempts.exists() else ""
            pytest.fail(f"not every run of {keys} started; attempts.log:\n{started}")
        time.sleep(0.2)
    time.sleep(3)  # lerobot-train is up
    proc.send_signal(signal.SIGINT)
    output, _ = proc.communicate(timeout=120)
    return output, proc.returncode


def _children_left(work: Path) -> list[str]:
    leftover = subprocess.run(["pgrep", "-f", str(work / "runs")], capture_output=True, text=True).stdout.split()
    return [pid for pid in leftover if int(pid) != os.getpid()]


def _starts(work: Path, key: str) -> int:
    attempts = work / "attempts.log"
    return attempts.read_text().count(key) if attempts.exists() else 0


@pytest.mark.slow  # ~1 min; the default suite keeps an interrupted run resuming from its checkpoint
def test_interrupted_grid_stops_its_runs_and_resumes(work, tmp_path):
    """Ctrl-C (SIGINT) on the driver: exit 130, the run in flight is stopped (no orphaned lerobot-train), no
    failure is recorded for it, nothing is retried; the same command then finishes the grid."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "lerobot_focal.benchmarks.grid.driver", *TINY_ARGS, "--methods", "wo_las",
           "--out", str(out), "--work", str(work)]
    before = _starts(work, "reach|wo_las|0")
    output, rc = _interrupt_once_training(cmd, work, ["reach|wo_las|0"])
    assert rc == 130, output
    assert "interrupted" in output
    assert _children_left(work) == []
    assert ResultsFile(out / "results.jsonl").records() == []  # neither ok nor failed
    assert _starts(work, "reach|wo_las|0") == before + 1  # not retried

    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert rerun.returncode == 0, rerun.stdout[-2000:] + rerun.stderr[-2000:]
    (record,) = ResultsFile(out / "results.jsonl").records()
    assert record.status == "ok" and record.key == "reach|wo_las|0"


def _grid_of_one_run(work: Path, out: Path, steps: int, method: str) -> tuple[list[str], Path]:
    """The driver command of a one-run grid (reach, `method`, seed 0, `steps` steps, an evaluation every 2) and
    that run's folder."""
    args = [*TINY_ARGS[:1], str(steps), *TINY_ARGS[2:]]
    cmd = [sys.executable, "-m", "lerobot_focal.benchmarks.grid.driver", *args, "--methods", method,
           "--out", str(out), "--work", str(work)]
    folder = PRESETS["cpu"].with_overrides(**{**TINY, "steps": steps}).runs_folder
    return cmd, work / "runs" / folder / "reach" / method / "seed0"


def _seeded_episodes(run_dir: Path) -> list[dict]:
    path = run_dir / "eval_episodes.jsonl"
    lines = path.read_text().splitlines() if path.exists() else []
    return [r for r in (json.loads(x) for x in lines if x.endswith("}")) if r["seed"] is not None]


def _interrupt_after_first_evaluation(cmd: list[str], run_dir: Path) -> None:
    """Start the driver, send SIGINT as soon as the run's first evaluation (2 episodes) is written."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.time() + 300
    while len(_seeded_episodes(run_dir)) < 2:
        assert proc.poll() is None and time.time() < deadline, "the run ended or stalled before its first evaluation"
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    output, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, output


def test_run_interrupted_after_an_evaluation_resumes_from_its_checkpoint(work, tmp_path):
    """SIGINT once the run's first evaluation is written: the rerun continues with LeRobot's own resume from the
    checkpoint saved at the newest completed evaluation, keeps the evaluations already done, and finishes."""
    cmd, run_dir = _grid_of_one_run(work, tmp_path / "out", steps=10, method="focal")  # 5 evaluations
    _interrupt_after_first_evaluation(cmd, run_dir)
    assert _children_left(work) == []
    first_evaluation = _seeded_episodes(run_dir)[:2]
    listed = subprocess.run([*cmd, "--dry-run"], capture_output=True, text=True, timeout=300).stdout
    assert "1 of them continue from a checkpoint: reach|focal|0 at step " in listed, listed

    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert rerun.returncode == 0, rerun.stdout[-2000:] + rerun.stderr[-2000:]
    (record,) = ResultsFile(tmp_path / "out" / "results.jsonl").records()
    assert record.status == "ok" and [c["step"] for c in record.curve] == [2, 4, 6, 8, 10]
    (resumed_at,) = record.resumed_from_steps
    assert f"reach|focal|0 at step {resumed_at}\n" in listed  # where --dry-run said it would continue
    # ... and how far the run had got: the success of every evaluation it completed
    line = next(x for x in listed.splitlines() if x.strip().startswith("reach|focal|0 (continues"))
    assert f"from step {resumed_at} of 10; success at each evaluation so far: 2: " in line
    assert line.count(" %") >= resumed_at // 2
    assert resumed_at in (2, 4, 6, 8) and record.lost_s >= 0 and len(record.spans) == 2
    seeded = _seeded_episodes(run_dir)
    assert seeded[:2] == first_evaluation and len(seeded) == 10  # kept, then the rest, nothing twice
    log = (run_dir / "train.log").read_text()
    assert "--resume=true" in log and "Resuming data order" in log  # LeRobot's own resume, mid-epoch
    assert f"resumed from step {resumed_at}" in (work / "attempts.log").read_text()
    said = rerun.stdout + rerun.stderr  # each evaluation's result as it lands, the kept ones not again
    assert "reach|focal|0: evaluation 5/5 (step 10)" in said and "evaluation 1/5" not in said
    ckpts = sorted(p.name for p in (run_dir / "train" / "checkpoints").iterdir())
    assert ckpts == ["000010", "last"]  # only the final checkpoint is kept


@pytest.mark.slow  # a second interrupted run (~1.5 min); the default suite has the resume that works
def test_a_resume_that_fails_is_not_tried_again_and_the_run_starts_over(work, tmp_path):
    """A checkpoint LeRobot cannot resume from (its saved configuration broken here) fails that attempt; the
    retry starts the run over instead of failing the same way, and the run still finishes."""
    cmd, run_dir = _grid_of_one_run(work, tmp_path / "out", steps=6, method="wo_fco_las")
    _interrupt_after_first_evaluation(cmd, run_dir)
    for config in (run_dir / "train" / "checkpoints").glob("*/pretrained_model/train_config.json"):
        config.write_text("{not json")
    key = "reach|wo_fco_las|0"
    before = [line for line in (work / "attempts.log").read_text().splitlines() if key in line]

    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert rerun.returncode == 0, rerun.stdout[-2000:] + rerun.stderr[-2000:]
    (record,) = ResultsFile(tmp_path / "out" / "results.jsonl").records()
    assert record.status == "ok" and record.resumed_from_steps is None
    assert [c["step"] for c in record.curve] == [2, 4, 6]
    starts = [line for line in (work / "attempts.log").read_text().splitlines() if key in line][len(before):]
    assert len(starts) == 2 and "resumed from step" in starts[0] and "resumed" not in starts[1]
    assert "the next attempt starts the run over" in rerun.stdout + rerun.stderr


def test_interrupted_parallel_grid_starts_none_of_its_queued_runs(work, tmp_path):
    """With --jobs 2 and four runs, Ctrl-C while two train: both are stopped, and the two queued runs are not
    started on the way out (worker threads freed by the stop used to pick them up before the pool shut down)."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "lerobot_focal.benchmarks.grid.driver", *TINY_ARGS, "--methods",
           "time_only_fco,freq_only_fco,fixed_r,anchor_0.4_0.5", "--jobs", "2", "--out", str(out),
           "--work", str(work)]
    keys = [f"reach|{m}|0" for m in ("time_only_fco", "freq_only_fco", "fixed_r", "anchor_0.4_0.5")]
    before = {key: _starts(work, key) for key in keys}
    output, rc = _interrupt_once_training(cmd, work, keys[:2])
    assert rc == 130, output
    assert "interrupted" in output
    assert _children_left(work) == []
    assert ResultsFile(out / "results.jsonl").records() == []
    assert {key: _starts(work, key) - before[key] for key in keys} == dict.fromkeys(keys[:2], 1) | dict.fromkeys(
        keys[2:], 0
    )
