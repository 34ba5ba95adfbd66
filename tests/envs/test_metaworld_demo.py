"""The README's MetaWorld demo module end to end with tiny settings (real collect, lerobot-train, lerobot-eval)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("metaworld")

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_metaworld_demo_tiny(tmp_path):
    out = tmp_path / "demo"
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    cmd = [sys.executable, "-m", "lerobot_focal.demos.metaworld", "--episodes", "2",
           "--steps", "4", "--batch-size", "8", "--eval-episodes", "2", "--eval-batch-size", "2",
           "--eval-episode-length", "30", "--output", str(out)]
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    assert "[demo] button-press-v3: success rate" in proc.stdout
    assert "the paper's FocalPolicy: 100.0%" in proc.stdout  # printed beside ours

    result = json.loads((out / "result.json").read_text())
    assert result["task"] == "button-press-v3" and result["train_steps"] == 4 and result["eval_episodes"] == 2
    assert result["obs"] == "state" and result["preset"] == "focal_cpu_state.json"
    assert result["paper_focal_success"] == 1.0
    assert 0.0 <= result["success_rate"] <= 1.0 and result["mean_action_total_variation"] > 0
    assert len(result["loss_curve"]["loss"]) == 4  # log_freq = 1 at 4 steps: one loss per step
    assert all(0 < e["length"] <= 30 for e in result["episodes"])
    assert set(result["seconds"]) == {"collect_s", "train_s", "eval_s", "total_s"}
    assert (out / "metaworld_demo.png").stat().st_size > 10_000
    assert (out / "train" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").exists()
