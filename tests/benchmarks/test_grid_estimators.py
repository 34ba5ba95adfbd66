"""The paper's estimator beside ours: fresh placements at every periodic evaluation, demos drawn per seed, the
re-score of a finished grid's final checkpoints, and the report's three numbers per cell."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lerobot_focal.benchmarks.grid.grid_presets import PRESETS
from lerobot_focal.benchmarks.grid.results import ResultsFile
from lerobot_focal.benchmarks.grid.seeds import (
    RESCORE_BLOCKS,
    check_seed_ranges,
    demo_seed_of,
    fresh_offset,
    run_seed_ranges,
)


def _periodic_seeds(preset, seed: int) -> list[set[int]]:
    """The reset seeds each periodic evaluation of training seed ``seed`` places its objects with: LeRobot resets
    with seed … seed + N − 1, the env adds its offset plus the evaluation episodes already recorded."""
    n, evals = preset.eval_episodes, preset.steps // preset.eval_every
    if preset.periodic_eval == "fixed":
        return [set(range(seed, seed + n))] * evals
    return [{fresh_offset(preset, seed) + i * n + s for s in range(seed, seed + n)} for i in range(evals)]


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_fresh_evaluations_are_distinct_per_seed_and_evaluation_and_clear_of_every_other_range(name):
    preset = PRESETS[name]
    check_seed_ranges(preset, preset.seeds, rescore_episodes=RESCORE_BLOCKS * preset.eval_episodes)
    others = []  # (seed, purpose, seeds) of everything that is not a periodic evaluation
    for k in preset.seeds:
        for r in run_seed_ranges(preset, k, RESCORE_BLOCKS * preset.eval_episodes)[1:]:
            others.append((k, r.purpose, set(range(r.start, r.stop))))
    evaluations = [(k, i, s) for k in preset.seeds for i, s in enumerate(_periodic_seeds(preset, k))]
    for k, i, seeds in evaluations:
        assert len(seeds) == preset.eval_episodes
        for j, purpose, other in others:
            assert not seeds & other, (name, k, i, purpose, j)
    if preset.periodic_eval == "fresh":
        for a, (k, i, seeds) in enumerate(evaluations):
            for j, e, other in evaluations[a + 1:]:
                assert not seeds & other, (name, (k, i), (j, e))  # every evaluation of every seed: new placements
    demos = [set(range(r.start, r.stop))
             for k in preset.seeds for r in run_seed_ranges(preset, k) if r.purpose == "demos"]
    if preset.demos_per_seed:
        assert all(not a & b for i, a in enumerate(demos) for b in demos[i + 1:])
    else:
        assert all(d == demos[0] for d in demos)


def test_cpu_fair_is_cpu_plateau_with_the_papers_estimator_and_demos_per_seed():
    fair, plateau = PRESETS["cpu_fair"].to_dict(), PRESETS["cpu_plateau"].to_dict()
    assert (fair["periodic_eval"], fair["demos_per_seed"]) == ("fresh", True)
    assert (plateau["periodic_eval"], plateau["demos_per_seed"]) == ("fixed", False)
    differ = {k for k in fair if fair[k] != plateau[k]}
    # and the baselines' own learning rates (the lr sweep's choice, docs/benchmarks/lr_sweep_fair) and ACT's own
    # budget (what the CPU affords, docs/benchmarks.md)
    assert differ == {"name", "notes", "periodic_eval", "demos_per_seed", "method_lr", "method_steps", "steps",
                      "eval_every"}
    assert fair["steps"] // fair["eval_every"] == plateau["steps"] // plateau["eval_every"] == 16  # evaluations
    assert dict(fair["method_lr"]) == {"diffusion_ema": 1e-3, "act": 1e-4}
    act = PRESETS["cpu_fair"].for_method("act")
    assert (act.steps, act.eval_every) == (10000, 625)  # the same 16 evaluations over its own steps


def test_overlapping_seed_ranges_are_refused_before_anything_runs(tmp_path):
    from lerobot_focal.benchmarks.grid import driver

    base = ["--tasks", "pick-place", "--methods", "focal", "--out", str(tmp_path / "o"), "--work", str(tmp_path),
            "--dry-run"]
    # Per-seed demos from 98000: seed 2's run into the held-out seeds (100000 …).
    with pytest.raises(SystemExit, match="the demos of seed 2 may use reset seeds 100000 to 100029"):
        driver.main(["--preset", "cpu_fair", "--demo-seed", "98000", *base])
    assert driver.main(["--preset", "cpu_plateau", "--demo-seed", "98000", *base]) == 0  # one set of demos: fits
    # 40 000 fresh evaluation episodes per run would run into the next seed's.
    with pytest.raises(SystemExit, match="fresh periodic evaluations"):
        driver.main(["--preset", "cpu_fair", "--eval-every", "4", *base])
    with pytest.raises(SystemExit, match="final evaluation: 5000 episodes per run"):
        driver.main(["--preset", "cpu_fair", "--final-episodes", "5000", *base])
    assert not (tmp_path / "o").exists()


def test_each_seed_trains_on_its_own_demos_and_evaluates_its_own_placements(tmp_path):
    from lerobot_focal.benchmarks.grid import driver
    from lerobot_focal.benchmarks.grid.run import train_command

    def specs(preset: str) -> list:
        args = driver.parse_args(["--preset", preset, "--tasks", "pick-place", "--methods", "focal",
                                  "--out", str(tmp_path / "o"), "--work", str(tmp_path)])
        return driver.build_specs(args)[0]

    fair = specs("cpu_fair")
    roots = {s.data.train_root for s in fair}
    assert len(roots) == 3 and {r.name for r in roots} == {"train-demos1000", "train-demos2000", "train-demos3000"}
    assert len({s.data.heldout_root for s in fair}) == 1 and [s.data.demo_seed for s in fair] == [1000, 2000, 3000]
    offsets = [[a for a in train_command(s) if a.startswith("--env.fresh_reset_seeds=")] for s in fair]
    assert offsets == [["--env.fresh_reset_seeds=1000000"], ["--env.fresh_reset_seeds=1010000"],
                       ["--env.fresh_reset_seeds=1020000"]]
    plateau = specs("cpu_plateau")
    assert {s.data.train_root.name for s in plateau} == {"train"}  # today's layout, committed grids unchanged
    assert not any(a.startswith("--env.fresh_reset_seeds") for s in plateau for a in train_command(s))
    # cpu_fair's seed 1 draws --demo-seed 2000's placements, yet never reads a folder of another preset.
    assert all(PRESETS["cpu_fair"].data_folder in str(r) for r in roots)
    assert demo_seed_of(PRESETS["cpu_fair"], 1) == 2000


def test_block_scores_take_the_top_k_of_block_means_in_seed_order():
    from lerobot_focal.benchmarks.grid.rescore import block_scores

    successes = [1, 0, 0, 0,  1, 1, 0, 0,  1, 1, 1, 0,  1, 1, 1, 1,  0, 0, 0, 0,  1, 0, 1, 0]  # 6 blocks of 4
    episodes = [{"seed": 500 + i, "success": bool(x)} for i, x in enumerate(successes)]
    scores = block_scores(list(reversed(episodes)), block=4, top_k=3)  # written as they finished: any order
    assert scores["blocks"] == [0.25, 0.5, 0.75, 1.0, 0.0, 0.5]
    assert scores["top_k"] == pytest.approx((1.0 + 0.75 + 0.5) / 3)
    assert scores["mean"] == pytest.approx(12 / 24) and scores["episodes"] == 24
    with pytest.raises(ValueError, match="whole blocks"):
        block_scores(episodes[:-1], block=4, top_k=3)


def _record(task: str, method: str, seed: int, top: float, fresh: float, periodic: str) -> dict:
    curve = [{"step": 500 * (i + 1), "success": top - 0.01 * i, "atv": 0.1, "length": 100} for i in range(16)]
    return {"key": f"{task}|{method}|{seed}", "status": "ok", "task": task, "method": method, "seed": seed,
            "success_top_k": top, "success_final": fresh, "success_fresh": fresh, "fresh_episodes": 50,
            "periodic_eval": periodic, "atv": 0.1, "curve": curve, "compounding_curve": [0.1, 0.2],
            "compounding_error": 0.2, "ts_score": 0.1, "latency_ms": 2.0, "nfe": 1.0, "wall_s": 600.0,
            "update_s_per_step": 0.06}


def test_report_and_summary_show_the_papers_top5_todays_and_the_fresh_episodes(tmp_path):
    from lerobot_focal.benchmarks.grid.report import write_report

    fixed_dir, fresh_dir = tmp_path / "fixed", tmp_path / "fresh"
    for out, preset, periodic in ((fixed_dir, "cpu_plateau", "fixed"), (fresh_dir, "cpu_fair", "fresh")):
        out.mkdir()
        grid = {"preset": PRESETS[preset].to_dict(), "overrides": {}, "tasks": ["pick-place"],
                "methods": ["focal"], "seeds": [0, 1]}
        (out / "grid.json").write_text(json.dumps(grid))
        results = ResultsFile(out / "results.jsonl")
        results.append(_record("pick-place", "focal", 0, 0.40, 0.30, periodic))
        results.append(_record("pick-place", "focal", 1, 0.50, 0.40, periodic))

    # A fixed-episode grid: the paper's number is n/a until the re-score has run, then its top-5 of blocks.
    report = write_report(fixed_dir).read_text()
    assert "| FocalPolicy | n/a / 45.0 / 35.0 |" in report
    (fixed_dir / "rescore.json").write_text(json.dumps({
        "pick-place|focal|0": {"top_k": 0.55, "mean": 0.31, "blocks": [0.55] * 15, "episodes": 300},
        "pick-place|focal|1": {"top_k": 0.65, "mean": 0.41, "blocks": [0.65] * 15, "episodes": 300}}))
    report = write_report(fixed_dir).read_text()
    assert "| FocalPolicy | 60.0 / 45.0 / 35.0 |" in report
    assert "pick-place · focal · 0 31.0, pick-place · focal · 1 41.0" in report
    entry = json.loads((fixed_dir / "summary.json").read_text())["methods"]["focal"]["pick-place"]
    assert entry["top5_paper_mean"] == pytest.approx(0.60) and entry["top5_paper_std"] == pytest.approx(0.05)
    assert entry["top5_mean"] == pytest.approx(0.45) and entry["top5_fixed_mean"] == pytest.approx(0.45)
    assert entry["final_mean"] == pytest.approx(0.35) and entry["rescore_mean"] == pytest.approx(0.36)

    # A grid evaluated on fresh placements: its own top-5 is the paper's; the fixed-episode one does not exist.
    report = write_report(fresh_dir).read_text()
    assert "| FocalPolicy | 45.0 / n/a / 35.0 |" in report
    entry = json.loads((fresh_dir / "summary.json").read_text())["methods"]["focal"]["pick-place"]
    assert entry["top5_paper_mean"] == pytest.approx(0.45) and entry["top5_paper_std"] == pytest.approx(0.05)
    assert entry["top5_fixed_mean"] is None and entry["top5_mean"] == pytest.approx(0.45)
    assert entry["periodic_eval"] == ["fresh"]


def _placements_of_one_evaluation(cfg, seeds: list[int]) -> np.ndarray:
    """Object and goal positions at reset of the envs LeRobot builds for one evaluation, and their episodes
    played out (a few zero actions, episode_length 3) so that the env records them as LeRobot's rollout does."""
    (vec,) = [v for suite in cfg.create_envs(len(seeds)).values() for v in suite.values()]
    try:
        obs, _ = vec.reset(seed=seeds)
        placements = np.concatenate([obs["environment_state"][:, 4:7], obs["environment_state"][:, 36:39]], axis=1)
        for _ in range(3):
            vec.step(np.zeros((len(seeds), 4), dtype=np.float32))
    finally:
        vec.close()
    return placements


def test_a_fresh_evaluation_resets_other_placements_than_the_last_one(tmp_path):
    """End to end through the env config LeRobot's evaluation builds its envs from: with fresh_reset_seeds the
    same reset seeds place the objects elsewhere at the next evaluation; without, in the same places."""
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    def config(name: str, fresh: int | None) -> FocalMetaworldEnvConfig:
        return FocalMetaworldEnvConfig(task="pick-place", obs_type="state", env_state=True, episode_length=3,
                                       render_videos=False, metrics_path=str(tmp_path / f"{name}.jsonl"),
                                       fresh_reset_seeds=fresh)

    fixed = config("fixed", None)
    first, second = (_placements_of_one_evaluation(fixed, [0, 1]) for _ in range(2))
    np.testing.assert_array_equal(first, second)  # today: the same placements at every evaluation
    fresh = config("fresh", 1_000_000)
    first, second = (_placements_of_one_evaluation(fresh, [0, 1]) for _ in range(2))
    assert np.abs(first - second).max() > 1e-3  # new placements at the second evaluation
    assert not np.allclose(first[0], first[1])
    seeds = [json.loads(x)["seed"] for x in (tmp_path / "fresh.jsonl").read_text().splitlines()]
    assert sorted(seeds) == [1_000_000, 1_000_001, 1_000_002, 1_000_003]  # recorded: the seeds that placed them


@pytest.mark.subprocess
def test_a_tiny_grid_evaluates_fresh_placements_and_its_final_checkpoint_is_rescored(tmp_path):
    """A real run (reach, 4 steps, an evaluation of 2 episodes every 2 steps) with --periodic-eval fresh: LeRobot's
    two periodic evaluations reset other placements; then `lerobot-focal-bench rescore` scores its final checkpoint
    on 3 blocks of 2 fresh episodes and the report shows the numbers (committed grids keep no checkpoints)."""
    from lerobot_focal.benchmarks.cli import main as bench

    out, work = tmp_path / "out", tmp_path / "work"
    tiny = ["--preset", "cpu", "--steps", "4", "--eval-every", "2", "--eval-episodes", "2", "--demos", "2",
            "--heldout-demos", "1", "--episode-length", "100", "--batch-size", "8", "--tasks", "reach", "--seeds",
            "0", "--methods", "focal", "--periodic-eval", "fresh", "--out", str(out), "--work", str(work)]
    assert bench(["grid", *tiny]) == 0
    (record,) = ResultsFile(out / "results.jsonl").records()
    assert record.status == "ok" and record.periodic_eval == "fresh"
    run_dir = Path(record.run_dir)
    seeds = [json.loads(x)["seed"] for x in (run_dir / "eval_episodes.jsonl").read_text().splitlines()]
    seeds = [s for s in seeds if s is not None]
    assert sorted(seeds) == [1_000_000, 1_000_001, 1_000_002, 1_000_003]  # evaluation 2 did not replay evaluation 1

    assert bench(["rescore", "--out", str(out), "--work", str(work), "--blocks", "3"]) == 0
    entry = json.loads((out / "rescore.json").read_text())["reach|focal|0"]
    assert entry["episodes"] == 6 and len(entry["blocks"]) == 3 and entry["first_seed"] == 400_000
    episodes = [json.loads(x) for x in (run_dir / "rescore_episodes.jsonl").read_text().splitlines()]
    assert sorted(e["seed"] for e in episodes if e["seed"] is not None) == list(range(400_000, 400_006))
    assert entry["mean"] == pytest.approx(np.mean([e["success"] for e in episodes if e["seed"] is not None]))
    summary = json.loads((out / "summary.json").read_text())["methods"]["focal"]["reach"]
    assert summary["top5_paper_mean"] == pytest.approx(record.success_top_k)  # fresh: the grid's own top-5
    assert summary["rescore_mean"] == pytest.approx(entry["mean"])
    assert "## Three estimators" in (out / "report.md").read_text()
