"""The baselines at their own best (issue 31): `diffusion_ema` and LeRobot's `act` as grid methods, each at its
own learning rate, and the `fair` phases; end to end at toy scale, with latency and NFE measured for both."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lerobot_focal.benchmarks.grid import driver
from lerobot_focal.benchmarks.grid.driver import build_specs, merged_grid, parse_args
from lerobot_focal.benchmarks.grid.grid_presets import PRESETS
from lerobot_focal.benchmarks.grid.methods import ACT_CHUNK, METHODS, resolve_method_phases
from lerobot_focal.benchmarks.grid.results import ResultsFile
from tests.benchmarks.test_grid_runs import TINY_ARGS, work  # noqa: F401  (the module's tiny reach datasets)


def _args(method: str, preset) -> list[str]:
    return METHODS[method].train_args(preset)


def test_act_is_lerobots_act_with_the_changes_its_docstring_lists():
    args = _args("act", PRESETS["cpu_fair"])
    assert args[0] == "--policy.type=act"
    assert f"--policy.chunk_size={ACT_CHUNK}" in args and f"--policy.n_action_steps={ACT_CHUNK}" in args
    assert "--policy.dim_model=128" in args and "--policy.dim_feedforward=800" in args
    assert "--policy.optimizer_lr=0.0001" in args  # the rate cpu_fair's lr sweep chose, not the preset's 1e-3
    assert "--policy.optimizer_lr=1e-05" in _args("act", PRESETS["cpu_plateau"])  # elsewhere its authors' rate
    # ACT has no U-Net and no scheduler: LeRobot would refuse those flags.
    assert not any(a.startswith(("--policy.down_dims", "--policy.scheduler")) for a in args)
    assert not any("n_obs_steps" in a for a in args)  # ACT takes one observation step
    paper = _args("act", PRESETS["paper"])
    assert not any("dim_model" in a or "dim_feedforward" in a for a in paper)  # ACT's default size on a GPU
    with pytest.raises(ValueError, match="environment_state"):
        _args("act", PRESETS["cpu"].with_overrides(env_state=False))


def test_diffusion_ema_gets_dp3_chunking_and_ddim_10():
    args = _args("diffusion_ema", PRESETS["cpu_fair"])
    assert args[0] == "--policy.type=diffusion_ema"
    for flag in ("--policy.n_obs_steps=2", "--policy.horizon=16", "--policy.n_action_steps=8",
                 "--policy.noise_scheduler_type=DDIM", "--policy.num_inference_steps=10",
                 "--policy.down_dims=[32,64,128]", "--policy.scheduler_warmup_steps=100"):
        assert flag in args


def test_dp3_gets_focal_pcs_encoder_and_cloud_with_dp3_chunking():
    """Every flag is a DP3Config field; the cloud and the encoder widths are focal_pc's, the chunking and DDIM 10
    diffusion_ema's, and no object poses are needed or read."""
    import dataclasses

    from lerobot_focal.benchmarks.grid.methods import given
    from lerobot_focal.policy.dp3 import DP3Config

    preset = PRESETS["cpu_fair"]
    args = _args("dp3", preset)
    assert args[0] == "--policy.type=dp3"
    fields = {f.name for f in dataclasses.fields(DP3Config)}
    assert {a.split("=")[0].removeprefix("--policy.") for a in args[1:]} <= fields
    widths = [a for a in _args("focal_pc", preset) if "_feature_dim=" in a]
    assert widths == ["--policy.pointcloud_feature_dim=64", "--policy.state_feature_dim=64"]
    for flag in (*widths, "--policy.n_obs_steps=2", "--policy.horizon=16", "--policy.n_action_steps=8",
                 "--policy.noise_scheduler_type=DDIM", "--policy.num_inference_steps=10",
                 "--policy.down_dims=[32,64,128]", "--policy.scheduler_warmup_steps=100"):
        assert flag in args
    assert METHODS["dp3"].obs_type_for(preset) == METHODS["focal_pc"].obs_type_for(preset) == "pointcloud"
    assert _args("dp3", preset.with_overrides(env_state=False)) == args
    assert not any(a.endswith("_feature_dim=64") for a in _args("dp3", PRESETS["paper"]))  # DP3's own 64 there
    assert given("dp3", json.loads(json.dumps(preset.to_dict()))) | {"lr": ""} == {
        "lr": "", "schedule": "cosine, 100 warm-up", "acts": "EMA weights", "chunk": "16 / 8",
        "inputs": "512-pt cloud + 9-d state", "steps": str(preset.steps)}


def test_cloud_point_counts_and_table_crop_reach_the_demos_and_every_evaluation_env(tmp_path, monkeypatch):
    """DP3's counts (1024 in the demos, 512 in the evaluation env): the demos are collected at the training count
    into a folder of their own, shared by every evaluation count; the evaluation envs of a point-cloud run (the
    periodic ones inside lerobot-train and the final lerobot-eval) make clouds of the evaluation count, and the
    report's table says so. A low-dimensional run is not given a point count."""
    from lerobot_focal.benchmarks.grid import demos
    from lerobot_focal.benchmarks.grid.methods import given
    from lerobot_focal.benchmarks.grid.run import final_eval_command, train_command

    def specs(*extra):
        argv = ["--preset", "cpu_fair", "--tasks", "pick-place", "--methods", "focal_pc,focal", "--seeds", "0",
                "--out", str(tmp_path / "out"), "--work", str(tmp_path / "work"), *extra]
        return build_specs(parse_args(argv))[0]

    (dp3_pc, dp3_state), (dense_pc, _), (plain_pc, _) = (
        specs("--train-points", "1024", "--eval-points", "512"), specs("--train-points", "1024",
                                                                       "--eval-points", "1024"), specs())
    assert "train_points=1024" in str(dp3_pc.data.train_root) and dp3_pc.data == dense_pc.data != plain_pc.data
    assert dp3_pc.run_dir != dense_pc.run_dir
    for cmd in (final_eval_command(dp3_pc, tmp_path / "ckpt"), train_command(dp3_pc)):
        assert "--env.num_points=512" in cmd
    assert not any(a.startswith("--env.num_points") for a in final_eval_command(dp3_state, tmp_path / "ckpt"))
    commands = []
    monkeypatch.setattr(demos, "run_logged", lambda cmd, *a, **k: commands.append(cmd))
    with pytest.raises(FileNotFoundError):  # nothing was collected (no info.json); the command is what matters
        demos._collect(tmp_path / "d", "local/x", "pick-place", 10, 1000, dp3_pc.preset, tmp_path / "log",
                       "pointcloud")
    assert commands[0][commands[0].index("--num_points") + 1] == "1024"
    assert given("focal_pc", json.loads(json.dumps(dp3_pc.preset.to_dict())))["inputs"] == (
        "1024-pt (evaluated on 512) cloud + 9-d state")
    # The table kept in the clouds (DP3's crop keeps some): its own demos, and every cloud of the run keeps it.
    table_pc, _ = specs("--table-clearance", "none")
    assert "table_clearance=None" in str(table_pc.data.train_root) and table_pc.data != plain_pc.data
    assert "--env.table_clearance=null" in final_eval_command(table_pc, tmp_path / "ckpt")
    assert "--env.table_clearance=0.005" in final_eval_command(plain_pc, tmp_path / "ckpt")
    commands.clear()
    with pytest.raises(FileNotFoundError):
        demos._collect(tmp_path / "d", "local/x", "pick-place", 10, 1000, table_pc.preset, tmp_path / "log",
                       "pointcloud")
    assert commands[0][commands[0].index("--table_clearance") + 1] == "none"
    from lerobot_focal.datasets.making.collect import parse_args as collect_args

    assert collect_args(["--root", "r", "--table_clearance", "none"]).table_clearance is None
    assert given("focal_pc", json.loads(json.dumps(table_pc.preset.to_dict())))["inputs"] == (
        "512-pt cloud (table kept) + 9-d state")
    with pytest.raises(SystemExit):
        specs("--table-clearance", "-1")


def test_learning_rates_per_method_and_lr_for_every_method(tmp_path):
    preset = PRESETS["cpu_fair"].with_overrides(method_lr=(("diffusion_ema", 3e-4),))
    assert preset.lr_for("diffusion_ema") == 3e-4 and preset.lr_for("focal") == preset.lr
    assert preset.lr_for("act", 1e-5) == 1e-5
    assert preset.with_overrides(method_lr=(("act", 1e-4),)).lr_for("act", 1e-5) == 1e-4

    def spec(*extra):
        argv = ["--preset", "cpu_fair", "--tasks", "disassemble", "--methods", "diffusion_ema,act", "--seeds", "0",
                "--out", str(tmp_path / "out"), "--work", str(tmp_path / "work"), *extra]
        return build_specs(parse_args(argv))

    plain, _ = spec()
    # --lr sets every method's rate, ACT's and the preset's per-method ones included, even at the preset's value,
    # and keeps its runs in their own folder.
    for lr in ("1e-3", "1e-4"):
        specs, grid = spec("--lr", lr)
        for s in specs:
            assert f"--policy.optimizer_lr={float(lr)}" in METHODS[s.method].train_args(s.preset)
            assert s.run_dir.parts[-4] == f"cpu_fair+lr={float(lr)}" and s.data == plain[0].data
    # A sweep's results directory accepts its next invocation after a chosen rate is recorded in the preset.
    recorded = json.loads(json.dumps(grid, default=str))
    later = json.loads(json.dumps(grid, default=str))
    later["preset"]["method_lr"] = [["diffusion_ema", 3e-4]]
    assert merged_grid(recorded, later, tmp_path)["methods"] == ["diffusion_ema", "act"]
    without_lr = json.loads(json.dumps(spec()[1], default=str))
    changed = json.loads(json.dumps(without_lr))
    changed["preset"]["method_lr"] = [["diffusion_ema", 3e-4]]
    # Without --lr the per-method rates are what runs measure: free to change until diffusion_ema's first run lands.
    assert merged_grid(without_lr, changed, tmp_path)["methods"] == ["diffusion_ema", "act"]
    from tests.benchmarks.test_grid_estimators import _record

    ResultsFile(tmp_path / "results.jsonl").append(_record("disassemble", "diffusion_ema", 0, 0.5, 0.4, "fresh"))
    with pytest.raises(SystemExit, match="method_lr"):
        merged_grid(without_lr, changed, tmp_path)


def test_constant_schedule_keeps_the_rate_for_the_methods_that_decay_it(tmp_path):
    """The plateau probe's schedule: focal and diffusion_ema get LeRobot's constant-with-warm-up schedule (and it
    builds and holds the rate to the last step), ACT has no schedule flag either way, and the override names the
    runs' folder so a probe never reuses the grid's runs."""
    import torch

    from lerobot_focal.benchmarks.grid.methods import given
    from lerobot_focal.policy.configuration_focal import FocalConfig
    from lerobot_focal.policy.diffusion_ema import DiffusionEmaConfig

    argv = ["--preset", "cpu_fair", "--tasks", "disassemble", "--methods", "focal,diffusion_ema,act", "--seeds", "0",
            "--out", str(tmp_path / "out"), "--work", str(tmp_path / "work"), "--schedule", "constant"]
    specs, grid = build_specs(parse_args(argv))
    flag = "--policy.scheduler_name=constant_with_warmup"
    for s in specs:
        args = METHODS[s.method].train_args(s.preset)
        assert (flag in args) == (s.method != "act"), s.method
        assert not any(a.startswith("--policy.scheduler_name") for a in _args(s.method, PRESETS["cpu_fair"]))
        assert s.run_dir.parts[-4] == "cpu_fair+schedule=constant"
    assert given("focal", grid["preset"])["schedule"] == "constant, 100 warm-up"
    for config in (FocalConfig(scheduler_name="constant_with_warmup", scheduler_warmup_steps=10),
                   DiffusionEmaConfig(scheduler_name="constant_with_warmup", scheduler_warmup_steps=10)):
        optimizer = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1e-3)
        scheduler = config.get_scheduler_preset().build(optimizer, num_training_steps=100)
        rates = []
        for _ in range(100):
            optimizer.step()
            scheduler.step()
            rates.append(optimizer.param_groups[0]["lr"])
        assert rates[4] < 1e-3 and rates[20] == rates[-1] == 1e-3, type(config).__name__


def test_fair_phases_answer_the_main_question_first():
    phases = [[m.name for m in p] for p in resolve_method_phases("fair")]
    assert phases == [["focal", "diffusion_ema", "act"], ["wo_fco_las"]]


@pytest.mark.subprocess  # ~2 min each (lerobot-train and lerobot-eval); ACT's grid run is in the default suite
@pytest.mark.parametrize(("method", "nfe"), [
    pytest.param("diffusion_ema", 10.0, marks=pytest.mark.slow),  # its training: tests/policy/test_diffusion_ema.py
    ("act", 1.0),
])
def test_baselines_run_in_the_grid_with_latency_and_nfe(work, tmp_path, method, nfe):  # noqa: F811
    out = tmp_path / "out"
    assert driver.main([*TINY_ARGS, "--preset", "cpu_fair", "--methods", method, "--out", str(out),
                        "--work", str(work), "--final-episodes", "2"]) == 0
    (record,) = ResultsFile(out / "results.jsonl").records()
    assert record.status == "ok" and record.key == f"reach|{method}|0"
    assert [c["step"] for c in record.curve] == [2, 4] and record.fresh_episodes == 2
    assert record.nfe == nfe  # network calls per chunk, counted by hooks (EMA and online alike)
    assert record.latency_ms > 0
    cfg = json.loads(next(Path(record.run_dir).rglob("pretrained_model/config.json")).read_text())
    assert cfg["type"] == method
    if method == "act":  # LeRobot's defaults but the rate the preset's lr sweep chose
        assert cfg["chunk_size"] == ACT_CHUNK and cfg["dim_model"] == 128 and cfg["optimizer_lr"] == 1e-4
    else:
        assert cfg["use_ema"] is True and cfg["num_inference_steps"] == 10


def test_report_says_what_each_method_was_given(tmp_path):
    from lerobot_focal.benchmarks.grid.report import write_report
    from tests.benchmarks.test_grid_estimators import _record

    preset = PRESETS["cpu_fair"].with_overrides(method_lr=(("diffusion_ema", 3e-4),), method_steps=(("act", 12000),))
    methods = ["focal", "diffusion_ema", "act", "wo_fco_las"]
    grid = {"preset": json.loads(json.dumps(preset.to_dict())), "overrides": {}, "tasks": ["disassemble"],
            "methods": methods, "seeds": [0]}
    (tmp_path / "grid.json").write_text(json.dumps(grid))
    for m in methods:
        record = _record("disassemble", m, 0, 0.5, 0.4, "fresh")
        record["nfe"] = 10.0 if m == "diffusion_ema" else 1.0
        if m != "wo_fco_las":  # a record written before runs kept their thread count
            record["torch_threads"] = 2 if m == "act" else 1  # ACT alone on two cores
        ResultsFile(tmp_path / "results.jsonl").append(record)
    report = write_report(tmp_path).read_text()
    assert "## What each method was given" in report and "batch 64" in report and "20000 steps" in report
    cost = report.split("## Cost per run")[1].split("\n## ")[0]
    assert "| ACT | 1 | 2.0 | 0.060 | 10.0 | 2 |" in cost and "| FocalPolicy | 1 | 2.0 | 0.060 | 10.0 | 1 |" in cost
    assert "| w/o FCO & LAS | 1 | 2.0 | 0.060 | 10.0 | – |" in cost
    for row in (
        "| FocalPolicy | 0.001 | cosine, 100 warm-up | 20000 | EMA weights; consistency target EMA | 12 / 4 | "
        "9-d state + 39-d object poses | 1 |",
        "| DP with EMA (DDIM 10) | 0.0003 | cosine, 100 warm-up | 20000 | EMA weights | 16 / 8 | "
        "9-d state + 39-d object poses | 10 |",
        "| ACT | 1e-05 | constant | 12000 | online weights | 50 / 50 | 9-d state + 39-d object poses | 1 |",
        "| w/o FCO & LAS | 0.001 | cosine, 100 warm-up | 20000 | EMA weights; consistency target online | 12 / 4 |",
    ):
        assert row in report, row


def test_cost_table_flags_runs_of_one_method_on_machines_of_different_speed(tmp_path):
    """focal's two runs updated at 0.06 and 0.16 s/step (another session, a slower host): the cost table shows
    the range and says wall times compare only runs side by side; diffusion_ema's alike runs get no range."""
    from lerobot_focal.benchmarks.grid.report import write_report
    from tests.benchmarks.test_grid_estimators import _record

    grid = {"preset": json.loads(json.dumps(PRESETS["cpu_fair"].to_dict())), "overrides": {},
            "tasks": ["disassemble"], "methods": ["focal", "diffusion_ema"], "seeds": [0, 1]}
    (tmp_path / "grid.json").write_text(json.dumps(grid))
    for m, seed, update in (("focal", 0, 0.06), ("focal", 1, 0.16), ("diffusion_ema", 0, 0.05),
                            ("diffusion_ema", 1, 0.06)):
        record = _record("disassemble", m, seed, 0.5, 0.4, "fresh")
        record["update_s_per_step"] = update
        ResultsFile(tmp_path / "results.jsonl").append(record)
    cost = write_report(tmp_path).read_text().split("## Cost per run")[1].split("\n## ")[0]
    assert "| FocalPolicy | 1 | 2.0 | 0.110 (0.060–0.160) |" in cost
    assert "| DP with EMA (DDIM 10) | 1 | 2.0 | 0.055 |" in cost
    assert "compare methods only across runs that ran side by side" in cost


def test_cost_table_and_latency_goal_read_one_number_robust_to_a_slow_session(tmp_path):
    """ACT's three runs timed its network at 2 and 3 ms, and at 9 ms in a session when the machine was slow: the
    cost table and the latency goal both say the median, 3.0 ms (a mean over runs would say 4.7, a mean over
    tasks 5.8). Wall time depends on the task, so each task weighs alike: (60 + 120) / 2 min on
    pick-place and 300 on disassemble give 195 min (a mean over the three runs would say 160)."""
    from lerobot_focal.benchmarks.grid.report import write_report
    from tests.benchmarks.test_grid_estimators import _record

    grid = {"preset": json.loads(json.dumps(PRESETS["cpu_fair"].to_dict())), "overrides": {},
            "tasks": ["pick-place", "disassemble"], "methods": ["focal", "act"], "seeds": [0, 1]}
    (tmp_path / "grid.json").write_text(json.dumps(grid))
    for m, task, seed, latency, minutes in (("focal", "pick-place", 0, 4.0, 50), ("focal", "disassemble", 0, 4.0, 50),
                                            ("act", "pick-place", 0, 2.0, 60), ("act", "pick-place", 1, 3.0, 120),
                                            ("act", "disassemble", 0, 9.0, 300)):
        record = _record(task, m, seed, 0.5, 0.4, "fresh")
        record["latency_ms"], record["wall_s"] = latency, minutes * 60.0
        ResultsFile(tmp_path / "results.jsonl").append(record)
    report = write_report(tmp_path).read_text()
    cost = report.split("## Cost per run")[1].split("\n## ")[0]
    assert "| ACT | 1 | 3.0 | 0.060 | 195.0 |" in cost
    assert "latency per chunk: focal 4.0 ms vs ACT 3.0 ms, a ratio of 1.33 (NFE 1 vs 1) → within 1.5× of ACT's: " \
           "**met**" in report


def test_paired_table_keeps_a_method_whose_records_predate_the_fresh_episode_number(tmp_path):
    """A smoke grid recorded before runs scored fresh episodes: its top-5 pairs stay in the table, the fresh
    column says n/a; a grid with no pair at all gets no paired table."""
    from lerobot_focal.benchmarks.grid.report import write_report
    from tests.benchmarks.test_grid_estimators import _record

    grid = {"preset": json.loads(json.dumps(PRESETS["cpu"].to_dict())), "overrides": {},
            "tasks": ["disassemble"], "methods": ["focal", "diffusion"], "seeds": [0, 1]}
    (tmp_path / "grid.json").write_text(json.dumps(grid))
    for m, seed, top in (("focal", 0, 0.5), ("focal", 1, 0.6), ("diffusion", 0, 0.2), ("diffusion", 1, 0.4)):
        record = _record("disassemble", m, seed, top, 0.4, "fixed")
        del record["success_fresh"], record["fresh_episodes"]
        ResultsFile(tmp_path / "results.jsonl").append(record)
    report = write_report(tmp_path).read_text()
    assert "| DP (DDIM 10) | +25.0 [" in report and "(n=2; 2/0/0) | n/a |" in report
    grid["methods"] = ["focal"]
    (tmp_path / "grid.json").write_text(json.dumps(grid))
    assert "## Paired comparisons" not in write_report(tmp_path).read_text()


def test_a_method_trains_to_its_own_budget_with_as_many_evaluations(tmp_path):
    """method_steps: ACT's runs train 12000 steps with 16 evaluations (every 750), every other method the preset's
    20000; a budget that does not divide into the evaluations is refused; and a results folder recorded before
    the field existed accepts an invocation that sets it (the field is new there, not changed)."""
    import dataclasses

    from lerobot_focal.benchmarks.grid.run import train_command

    preset = PRESETS["cpu_fair"].with_overrides(method_steps=(("act", 12000),))
    argv = ["--preset", "cpu_fair", "--tasks", "disassemble", "--methods", "focal,act", "--seeds", "0",
            "--out", str(tmp_path / "out"), "--work", str(tmp_path / "w")]
    specs = {s.method: s for s in build_specs(parse_args(argv))[0]}
    assert (specs["focal"].preset.steps, specs["focal"].preset.eval_every) == (20000, 1250)
    act = preset.for_method("act")
    assert (act.steps, act.eval_every) == (12000, 750) and preset.for_method("focal") is preset
    command = train_command(dataclasses.replace(specs["act"], preset=act))
    assert "--steps=12000" in command and "--env_eval_freq=750" in command and "--save_freq=750" in command
    with pytest.raises(ValueError, match="not a multiple of the preset's 16 evaluations"):
        PRESETS["cpu_fair"].with_overrides(method_steps=(("act", 12001),)).for_method("act")
    # --steps shortens every method, ACT included (a smoke test of cpu_fair, the plateau probe's 24000 steps)
    short = {s.method: s.preset for s in build_specs(parse_args([*argv, "--steps", "400", "--eval-every", "25"]))[0]}
    assert {m: (p.steps, p.eval_every) for m, p in short.items()} == {"focal": (400, 25), "act": (400, 25)}
    _, grid = build_specs(parse_args(argv))
    recorded = json.loads(json.dumps(grid, default=str))
    del recorded["preset"]["method_steps"]  # as grid.json was written before the field existed
    later = json.loads(json.dumps(grid, default=str))
    later["preset"]["method_steps"] = [["act", 12000]]
    assert merged_grid(recorded, later, tmp_path)["methods"] == ["focal", "act"]


def test_a_methods_budget_may_change_until_its_first_run_lands(tmp_path):
    """A results folder whose grid.json gave ACT no budget of its own accepts an invocation that gives it one while
    the folder holds focal's runs only; once an ACT run has landed, the same change is refused (it would put runs
    of two budgets under one key), and so is a change of focal's own rate."""
    from tests.benchmarks.test_grid_estimators import _record

    argv = ["--preset", "cpu_fair", "--tasks", "disassemble", "--methods", "focal,act", "--seeds", "0",
            "--out", str(tmp_path), "--work", str(tmp_path / "w")]
    _, grid = build_specs(parse_args(argv))
    later = json.loads(json.dumps(grid, default=str))
    assert later["preset"]["method_steps"] == [["act", 10000]]  # cpu_fair's own
    earlier = json.loads(json.dumps(grid, default=str))
    earlier["preset"]["method_steps"] = []
    results = ResultsFile(tmp_path / "results.jsonl")
    results.append(_record("disassemble", "focal", 0, 0.5, 0.4, "fresh"))
    assert merged_grid(earlier, later, tmp_path)["methods"] == ["focal", "act"]
    other_focal_rate = json.loads(json.dumps(later))
    other_focal_rate["preset"]["method_lr"].append(["focal", 3e-4])
    with pytest.raises(SystemExit, match="preset method_lr"):
        merged_grid(later, other_focal_rate, tmp_path)
    results.append(_record("disassemble", "act", 0, 0.5, 0.4, "fresh"))
    with pytest.raises(SystemExit, match="preset method_steps"):
        merged_grid(earlier, later, tmp_path)


def test_dp3_is_compared_with_focal_on_the_same_point_clouds(tmp_path):
    """The report pairs DP3 with focal on point clouds (its rival on the same inputs), in the paired table, the
    goals and the latency line, and never with focal on object poses."""
    from lerobot_focal.benchmarks.grid.report import write_report
    from tests.benchmarks.test_grid_estimators import _record

    methods = ["focal", "focal_pc", "dp3"]
    grid = {"preset": json.loads(json.dumps(PRESETS["cpu_fair"].to_dict())), "overrides": {},
            "tasks": ["disassemble", "push-wall"], "methods": methods, "seeds": [0, 1]}
    (tmp_path / "grid.json").write_text(json.dumps(grid))
    tops = {"focal": 0.9, "focal_pc": 0.6, "dp3": 0.5}
    for m in methods:
        for task in grid["tasks"]:
            for seed in (0, 1):
                record = _record(task, m, seed, tops[m] + 0.05 * seed, tops[m], "fresh")
                record["latency_ms"], record["nfe"] = (20.0, 10.0) if m == "dp3" else (4.0, 1.0)
                ResultsFile(tmp_path / "results.jsonl").append(record)
    report = write_report(tmp_path).read_text()
    assert "| DP3 (512-pt cloud, DDIM 10) (against FocalPolicy (512-pt cloud)) | +10.0 [+10.0, +10.0]" in report
    assert ("- FocalPolicy (512-pt cloud) ≥ DP3 (512-pt cloud, DDIM 10) (top-5, paired over 4 task-seed pairs): "
            "+10.0 points") in report
    assert "latency per chunk: FocalPolicy (512-pt cloud) 4.0 ms vs DP3 (512-pt cloud, DDIM 10) 20.0 ms" in report
    assert "focal ≥ DP3" not in report


@pytest.mark.subprocess
@pytest.mark.slow  # ~2 min each; image focal's training: tests/robots/test_ur10e_loop.py
@pytest.mark.parametrize("method", ["focal_rgb", "diffusion_rgb", "act_rgb"])
def test_camera_methods_train_and_evaluate_on_rgb_and_state_only(work, tmp_path, method):  # noqa: F811
    """cpu_rgb: the demos hold an 84x84 camera and the state but no object poses; the policy reads the camera
    (cropped) and the state; LeRobot's evaluation renders the camera at the demos' size."""
    out = tmp_path / "out"
    assert driver.main([*TINY_ARGS, "--preset", "cpu_rgb", "--methods", method, "--out", str(out),
                        "--work", str(work), "--final-episodes", "2"]) == 0
    (record,) = ResultsFile(out / "results.jsonl").records()
    assert record.status == "ok" and [c["step"] for c in record.curve] == [2, 4] and record.fresh_episodes == 2
    cfg = json.loads(next(Path(record.run_dir).rglob("pretrained_model/config.json")).read_text())
    assert set(cfg["input_features"]) == {"observation.state", "observation.image"}
    assert cfg["input_features"]["observation.image"]["shape"] == [3, 84, 84]
    if method != "act_rgb":
        assert cfg["crop_shape"] == [76, 76]
    assert cfg["pretrained_backbone_weights"] is None
