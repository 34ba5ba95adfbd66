"""`lerobot-focal-bench rollout`: the loop-stage bookkeeping, and one real run of the timed `lerobot-rollout`."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from lerobot_focal.benchmarks.rollout_latency import steps_from_events, summarise


def _step(t: float, network: bool) -> list[tuple[str, float, float]]:
    """The events of one 30 Hz loop iteration starting at t (seconds), as the probe records them."""
    events = [("get_observation", t, t + 0.002), ("camera_read", t + 0.0005, t + 0.0015),
              ("inference", t + 0.003, t + 0.013 if network else t + 0.006),
              ("preprocessor", t + 0.003, t + 0.005), ("depth_to_cloud", t + 0.003, t + 0.0045),
              ("select_action", t + 0.005, t + 0.012 if network else t + 0.0055)]
    if network:
        events.append(("network", t + 0.0052, t + 0.0118))
    events.append(("send_action", t + 0.014, t + 0.015))
    return events


def test_events_become_steps_with_policy_steps_and_observation_to_command():
    events = [("run", 0.0, 0.0)]
    for i in range(60):
        events += _step(i / 30.0, network=i % 4 == 0)
    steps = steps_from_events(events, warmup_s=0.5)
    assert len(steps) == 60 - 15  # iterations starting in the first 0.5 s are dropped
    assert steps[0]["start"] == pytest.approx(15 / 30.0)
    policy = [s for s in steps if "network" in s]
    assert len(policy) == sum(1 for i in range(15, 60) if i % 4 == 0)
    assert all(s["obs_to_command"] == pytest.approx(0.013) for s in steps)  # end of observation -> command sent

    summary = summarise(steps, fps=30)
    assert summary["p50_total_ms"] == pytest.approx(13.0, abs=0.01)
    assert summary["stages_ms"]["network"]["policy_steps"]["p50"] == pytest.approx(6.6, abs=0.01)
    assert summary["stages_ms"]["inference"]["all_steps"]["p50"] == pytest.approx(3.0, abs=0.01)
    assert summary["fps_achieved"] == pytest.approx(30.0, abs=0.01)
    assert summary["late_periods"] == 0 and summary["costliest_stage_p99"] == "network"


def test_a_stall_shows_as_a_late_period_and_in_the_p99():
    events = [("run", 0.0, 0.0)]
    t = 0.0
    for i in range(200):
        events += _step(t, network=i % 4 == 0)
        t += 0.1 if i == 100 else 1 / 30.0
    summary = summarise(steps_from_events(events, warmup_s=0.0), fps=30)
    assert summary["late_periods"] == 1
    assert summary["period_ms"]["max"] == pytest.approx(100.0, abs=0.01)
    assert summary["fps_achieved"] < 30.0


@pytest.mark.slow
def test_timed_lerobot_rollout_on_the_twin_reports_every_stage(tmp_path):
    """The whole benchmark at a small resolution: a recorded dataset, a real `lerobot-train` checkpoint (point
    cloud from depth), LeRobot's `lerobot-rollout` with the probe, and the report files."""
    pytest.importorskip("mujoco")
    env = dict(os.environ, HF_HUB_OFFLINE="1", MUJOCO_GL="disable")
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "lerobot_focal.benchmarks.cli", "rollout", "--width", "96", "--height", "64",
         "--duration", "6", "--warmup-s", "1", "--train-steps", "2", "--configs", "pointcloud",
         "--work", str(tmp_path / "work"), "--out", str(out)],
        env=env, capture_output=True, text=True, timeout=900, check=False,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    result = json.loads((out / "rollout_latency.json").read_text())
    (config,) = result["configurations"]
    assert config["resolution"] == "96x64" and config["inputs"].startswith("512-point cloud")
    assert config["policy_steps"] >= 5 and config["steps"] > config["policy_steps"]
    assert 0 < config["p50_total_ms"] <= config["p99_total_ms"]
    stages = config["stages_ms"]
    for stage in ("get_observation", "camera_read", "inference", "preprocessor", "depth_to_cloud", "select_action",
                  "network", "send_action"):
        assert stages[stage]["policy_steps"]["p50"] > 0, stage
    # Nested stages never exceed their parent.
    assert stages["network"]["policy_steps"]["p50"] <= stages["select_action"]["policy_steps"]["p50"]
    assert stages["depth_to_cloud"]["policy_steps"]["p50"] <= stages["preprocessor"]["policy_steps"]["p50"]
    assert (out / "rollout_latency.md").read_text().count("512-point cloud") == 1
    assert (out / "rollout_latency.png").stat().st_size > 10_000
