"""The learning-rate sweep: one grid invocation per (method, lr) in its own results directory, and a summary that
picks each method's rate from what has landed."""

from __future__ import annotations

import argparse
import json

import pytest

from lerobot_focal.benchmarks.grid.diagnostics import lr_sweep
from lerobot_focal.benchmarks.grid.results import ResultsFile


def _record(method: str, fresh: float, top: float) -> dict:
    return {"key": f"disassemble|{method}|0", "status": "ok", "task": "disassemble", "method": method, "seed": 0,
            "success_top_k": top, "periodic_eval": "fresh", "success_final": top, "success_fresh": fresh,
            "fresh_episodes": 50, "latency_ms": 19.0, "nfe": 10.0, "n_params": 1000, "update_s_per_step": 0.05,
            "wall_s": 600.0, "curve": [{"step": 500, "success": 0.1}, {"step": 1000, "success": top}]}


def test_runs_parse_in_order_and_bad_ones_say_what_to_write():
    assert lr_sweep.parse_runs(["diffusion_ema=1e-4,3e-4", "act=1e-5"]) == [
        ("diffusion_ema", 1e-4), ("diffusion_ema", 3e-4), ("act", 1e-5)]
    for bad in ("diffusion_ema", "act=", "act=fast", "act=0"):
        with pytest.raises(argparse.ArgumentTypeError):
            lr_sweep.parse_runs([bad])


def test_each_rate_is_its_own_grid_and_the_summary_picks_by_fresh_episodes(tmp_path, capsys):
    out = tmp_path / "sweep"
    args = argparse.Namespace(preset="cpu_fair", task="disassemble", seed=0, out=out, work=tmp_path / "w",
                              grid_args=["--dry-run"])
    argv = lr_sweep.grid_argv(args, "diffusion_ema", 3e-4)
    assert argv[argv.index("--lr") + 1] == "0.0003" and argv[argv.index("--out") + 1] == str(out / "lr_0.0003")
    assert argv[-1] == "--dry-run" and argv[argv.index("--methods") + 1] == "diffusion_ema"

    runs = lr_sweep.parse_runs(["diffusion_ema=1e-4,3e-4,1e-3", "act=1e-5"])
    ResultsFile(out / "lr_0.0001" / "results.jsonl").append(_record("diffusion_ema", 0.40, 0.50))
    ResultsFile(out / "lr_0.0003" / "results.jsonl").append(_record("diffusion_ema", 0.60, 0.45))
    ResultsFile(out / "lr_0.001" / "results.jsonl").append(_record("diffusion_ema", 0.60, 0.55))
    assert lr_sweep.main(["--task", "disassemble", "--runs", "diffusion_ema=1e-4,3e-4,1e-3", "--runs", "act=1e-5",
                          "--out", str(out), "--summary-only"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary == lr_sweep.summarize(out, "disassemble", 0, runs)
    assert summary["chosen"] == {"diffusion_ema": {"lr": 1e-3, "complete": True}}  # tie on fresh: top-k decides
    assert [r["status"] for r in summary["runs"]] == ["done", "done", "done", "to do"]
    md = (out / "summary.md").read_text()
    assert "| diffusion_ema | 0.001 | 55 (fresh) | 55 | 60 (50) | 10 55 |" in md and "| act | 1e-05 | to do |" in md
    assert "**diffusion_ema**: lr 0.001" in md and md in capsys.readouterr().out
