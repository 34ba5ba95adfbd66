"""`lerobot-focal-bench act-precision` at toy scale: the grid's ACT trains twice from the same weights on a real
LeRobotDataset of MetaWorld demos (state + object poses, as the grid records them), in float32 and under bf16
autocast, and both land in the table, the JSON and the plot."""

from __future__ import annotations

import json

import pytest

from lerobot_focal.benchmarks.act_precision import main
from lerobot_focal.benchmarks.grid.methods import ACT_CHUNK
from lerobot_focal.datasets.making.collect import collect, parse_args

pytestmark = pytest.mark.slow  # in process, ~1 min on 2 cores: an expert episode collected, two ACTs trained briefly


def test_act_precision_trains_both_precisions_from_the_same_start(tmp_path):
    root = tmp_path / "data"
    collect(parse_args(["--root", str(root), "--repo_id", "local/reach", "--tasks", "reach", "--episodes", "1",
                        "--obs_types", "state,env_state", "--max_steps", "60", "--seed", "1000"]))
    assert main(["--data", str(root), "--repo-id", "local/reach", "--steps", "3", "--batch", "8",
                 "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "act_precision.json").read_text())
    assert result["chunk"] == ACT_CHUNK and result["width"] == [128, 800] and result["lr"] == 1e-4  # cpu_fair's ACT
    rows, curves = result["rows"], result["loss_curves"]
    assert set(rows) == set(curves) == {"float32", "bf16 autocast"}
    assert rows["float32"]["speedup"] == 1.0 and rows["float32"]["loss_difference"] == 0.0
    # Same weights, batch and noise at step 0: bf16 rounds the forward, so close to float32 and not equal to it.
    first = curves["bf16 autocast"][0] / curves["float32"][0]
    assert first != 1.0 and abs(first - 1.0) < 0.05
    assert all(len(c) == 3 for c in curves.values())
    assert "| bf16 autocast |" in (tmp_path / "out" / "act_precision.md").read_text()
    assert (tmp_path / "out" / "act_precision.png").stat().st_size > 5_000


def test_act_precision_times_dropout_and_threads_when_asked(tmp_path):
    """--dropout-cost adds float32 ACT with dropout 0 from the same weights (a timing row); --threads is recorded."""
    root = tmp_path / "data"
    collect(parse_args(["--root", str(root), "--repo_id", "local/reach", "--tasks", "reach", "--episodes", "1",
                        "--obs_types", "state,env_state", "--max_steps", "60", "--seed", "1000"]))
    assert main(["--data", str(root), "--repo-id", "local/reach", "--steps", "3", "--batch", "8", "--threads", "2",
                 "--dropout-cost", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "act_precision.json").read_text())
    curves = result["loss_curves"]
    assert result["threads"] == 2 and set(curves) == {"float32", "bf16 autocast", "float32, dropout 0"}
    # Same weights and batch at step 0, but no dropout masks: a different loss from float32's own.
    assert curves["float32, dropout 0"][0] != curves["float32"][0]
    assert result["rows"]["float32, dropout 0"]["ms_per_step"] > 0
    md = (tmp_path / "out" / "act_precision.md").read_text()
    assert "2 threads" in md and "of ACT's float32 step is its dropout" in md
    assert "--steps 3 --threads 2 --dropout-cost`" in md  # the table names the command that made it
    with pytest.raises(SystemExit):
        main(["--data", str(root), "--threads", "0"])
