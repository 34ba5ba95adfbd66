"""The training-step benchmark, for real: the point-cloud backward variants compute the same loss."""

from __future__ import annotations

import json

import pytest

from lerobot_focal.benchmarks.train_step import main as train_step_main
from lerobot_focal.datasets.making.synthetic import SyntheticSpec, write_synthetic_dataset


def test_pointcloud_variants_on_dataset_clouds_train_to_the_same_losses(tmp_path):
    root = tmp_path / "data"
    write_synthetic_dataset(root, SyntheticSpec(num_episodes=2, episode_length=12, num_points=128))
    assert train_step_main(["--inputs", "pointcloud", "--clouds", str(root), "--batch", "4", "--repeats", "1",
                            "--agreement-steps", "3", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "train_step_cpu_pointcloud.json").read_text())
    assert [r["variant"] for r in result["rows"]] == ["focal_adamw, dense max-pool backward",
                                                      "focal_adamw, winners-only backward (default)"]
    assert all(r["ms_per_step"] > 0 for r in result["rows"])
    agreement = result["agreement"]
    assert len(agreement["loss_dense"]) == len(agreement["loss_winners"]) == 3
    assert agreement["max_relative_loss_difference"] < 1e-4
    assert agreement["loss_dense"][-1] != agreement["loss_dense"][0]  # the steps trained
    winners = agreement["winners_per_cloud"]
    assert winners["points"] == 128 and 1 <= winners["mean"] <= winners["max"] <= 128
    assert f"--clouds {root}" in (tmp_path / "train_step_cpu_pointcloud.md").read_text()


def test_clouds_that_are_not_a_dataset_are_refused_before_anything_runs(tmp_path, capsys):
    with pytest.raises(SystemExit):
        train_step_main(["--inputs", "pointcloud", "--clouds", str(tmp_path), "--out", str(tmp_path)])
    assert "no LeRobotDataset there" in capsys.readouterr().err
    assert not (tmp_path / "train_step_cpu_pointcloud.json").exists()
