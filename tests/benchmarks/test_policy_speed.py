"""`lerobot-focal-bench speed` runs end to end on the CPU and its ratios are the ratios of its own medians."""

from __future__ import annotations

import json

import pytest
import torch

from lerobot_focal.benchmarks.cli import main as bench_main


@pytest.fixture
def torch_threads():
    """`--threads` sets the process's torch threads; give the rest of the suite its own back."""
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_speed_benchmark_writes_table_json_and_plot_with_consistent_ratios(tmp_path, torch_threads):
    assert bench_main(["speed", "--sizes", "cpu", "--device", "cpu", "--repeats", "1", "--no-ddpm",
                       "--threads", "1", "--cpu-train-batch", "4", "--out", str(tmp_path)]) == 0
    rows = {r["what"]: r for r in json.loads((tmp_path / "policy_speed_cpu.json").read_text())["rows"]}
    act_row = "ACT predict_action_chunk (50 actions, width 128/800)"
    assert list(rows) == ["bare U-Net forward", "focal predict_action_chunk (1 NFE)", act_row, "diffusion DDIM 10",
                          "plain flow-matching train step (batch 4)", "focal train step incl. EMA (batch 4)"]
    assert all(r["median_ms"] > 0 for r in rows.values())
    chunk = rows["focal predict_action_chunk (1 NFE)"]
    assert chunk["ratio"] == pytest.approx(chunk["median_ms"] / rows["bare U-Net forward"]["median_ms"])
    act = rows[act_row]  # LeRobot's ACT as the grid builds it, timed in the same round-robin as focal's chunk
    assert act["ratio"] == pytest.approx(act["median_ms"] / chunk["median_ms"]) and act["ratio_to"] == "focal"
    assert 1 < act["params_m"] < 20  # the transformer at the grid's width, not the U-Net's count
    ddim = rows["diffusion DDIM 10"]
    assert ddim["ratio"] == pytest.approx(ddim["median_ms"] / chunk["median_ms"])
    train = rows["focal train step incl. EMA (batch 4)"]
    assert train["ratio"] == pytest.approx(
        train["median_ms"] / rows["plain flow-matching train step (batch 4)"]["median_ms"])
    md = (tmp_path / "policy_speed_cpu.md").read_text()
    assert "| focal predict_action_chunk (1 NFE) |" in md
    assert md.startswith("# Policy speed") and "`lerobot-focal-bench speed --sizes cpu --device cpu" in md
    assert (tmp_path / "policy_speed_cpu.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
