"""The grid for real, at toy scale: scripted-expert datasets, `lerobot-train` processes with LeRobot's periodic
evaluation in `focal_metaworld`, checkpoint analysis, the resumable results file, and a real local Ray instance."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lerobot_focal.benchmarks.grid import driver
from lerobot_focal.benchmarks.grid.datasets import ensure_task_data
from lerobot_focal.benchmarks.grid.presets import PRESETS
from lerobot_focal.benchmarks.grid.results import ResultsFile
from lerobot_focal.benchmarks.grid.run import RunSpec

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
    assert record["status"] == "ok" and record["key"] == "reach|focal|0"
    assert [c["step"] for c in record["curve"]] == [2, 4]  # LeRobot evaluated at steps 2 and 4
    assert 0.0 <= record["success_top_k"] <= 1.0 and record["atv"] > 0
    assert record["nfe"] == 1.0  # one U-Net evaluation per executed chunk, counted by hooks
    assert record["latency_ms"] > 0 and len(record["compounding_curve"]) >= 20  # held-out reach: ~50 steps
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


def test_ray_executor_runs_gathers_and_retries(work, tmp_path):
    pytest.importorskip("ray")
    from lerobot_focal.benchmarks.grid.datasets import task_data
    from lerobot_focal.benchmarks.grid.executors import run_ray

    preset = PRESETS["cpu"].with_overrides(**TINY)
    good = RunSpec("reach", "diffusion", 0, preset, task_data(work, "reach", preset), work)
    broken_data = task_data(work / "nowhere", "reach", preset)  # no dataset there: lerobot-train fails
    bad = RunSpec("reach", "focal", 7, preset, broken_data, work)
    results = ResultsFile(tmp_path / "results.jsonl")
    run_ray([good, bad], results.append, retries=1, init_kwargs={"num_cpus": 2, "include_dashboard": False})

    records = {r["key"]: r for r in results.records()}
    assert records["reach|diffusion|0"]["status"] == "ok"
    assert records["reach|diffusion|0"]["nfe"] == 10.0  # DDIM 10, counted
    assert records["reach|focal|7"]["status"] == "failed"
    assert "lerobot-train exited" in records["reach|focal|7"]["error"]
    starts = (work / "attempts.log").read_text().splitlines()
    assert sum("reach|focal|7" in line for line in starts) == 2  # Ray retried the failed run once
    assert json.loads(results.path.read_text().splitlines()[0])  # whole lines only
