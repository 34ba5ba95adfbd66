"""`lerobot-focal-bench camera-step` at toy scale: every variant times, trains beside its base, and lands in the
table, the JSON and the plot; channels-last computes what the base computes."""

from __future__ import annotations

import json

import pytest

from lerobot_focal.benchmarks.camera_step import PAIRS, run

pytestmark = pytest.mark.slow  # in process, ~30 s on 2 cores: eight networks built, timed and trained


def test_camera_step_times_every_variant_and_compares_loss_curves(tmp_path):
    result = run(tmp_path, batch=2, repeats=1, loss_steps=3, image_size=32, crop=28, image_loss_steps=2)
    names = [r["variant"] for r in result["rows"]]
    assert names == ["low-dim", "cloud 512", "cloud 512, bf16 autocast", "cloud 256", "cloud 256, bf16 autocast",
                     "image", "image, channels-last", "image, bf16 autocast", "image, channels-last + bf16"]
    low = next(r for r in result["rows"] if r["variant"] == "low-dim")
    assert low["vs_low_dim"] == 1.0 and all(r["ms_per_step"] > 0 for r in result["rows"])
    assert set(result["loss_agreement"]) == {a for a, _ in PAIRS}
    for name, curve in result["loss_curves"].items():
        assert len(curve) == (2 if name.startswith("image") else 3) and all(v > 0 for v in curve), name
    # The same network and batch in another memory layout: the same losses, up to float rounding.
    assert result["loss_agreement"]["image, channels-last"]["relative_difference"] == pytest.approx(0, abs=1e-4)
    # bf16 rounds the forward: close to the base, not equal to it.
    bf16 = result["loss_agreement"]["cloud 512, bf16 autocast"]["relative_difference"]
    assert bf16 != 0 and abs(bf16) < 0.05
    saved = json.loads((tmp_path / "camera_step_cpu.json").read_text())
    assert saved["rows"] == result["rows"]
    assert "| cloud 256 | cloud 512 |" in (tmp_path / "camera_step_cpu.md").read_text()
    assert (tmp_path / "camera_step_cpu.png").stat().st_size > 5_000
