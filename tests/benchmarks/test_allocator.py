"""The grid's malloc settings reach its runs and change no arithmetic: the allocator benchmark, for real."""

from __future__ import annotations

import json

import pytest

from lerobot_focal.benchmarks.allocator import main as allocator_main
from lerobot_focal.benchmarks.grid.grid_presets import PRESETS
from lerobot_focal.benchmarks.grid.run import MALLOC_ENV, child_env


def test_runs_get_the_heap_only_malloc_settings_unless_the_user_set_their_own(monkeypatch):
    monkeypatch.delenv("MALLOC_MMAP_MAX_", raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "12345")
    env = child_env(PRESETS["cpu_plateau"])
    assert env["MALLOC_MMAP_MAX_"] == MALLOC_ENV["MALLOC_MMAP_MAX_"] == "0"
    assert env["MALLOC_TRIM_THRESHOLD_"] == "12345"  # the user's value wins
    assert env["OMP_NUM_THREADS"] == "1" and env["HF_HUB_OFFLINE"] == "1"  # the preset's threads
    monkeypatch.setenv("OMP_NUM_THREADS", "2")  # a run alone on two cores
    assert child_env(PRESETS["cpu_plateau"])["OMP_NUM_THREADS"] == "2"


@pytest.mark.subprocess
@pytest.mark.slow  # ~30 s: two child processes timed; the settings themselves are checked above
def test_allocator_benchmark_times_both_settings_in_child_processes_with_identical_results(tmp_path):
    assert allocator_main(["--inputs", "state", "--rounds", "1", "--steps", "2", "--batch", "8",
                           "--out", str(tmp_path)]) == 0  # exit 1 if the settings changed the loss or weights
    result = json.loads((tmp_path / "allocator_cpu.json").read_text())["inputs"]["state"]
    assert result["bit_identical"] is True
    assert all(ms > 0 for ms in result["ms_per_step"].values()) and result["speedup"] > 0
    assert "| state |" in (tmp_path / "allocator_cpu.md").read_text()
