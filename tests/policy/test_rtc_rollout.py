"""`lerobot-rollout --inference.type=rtc` with a focal checkpoint on the UR-10e twin, as real processes.

A short scripted dataset recorded from the twin (the `lerobot-focal-bench rollout` recorder), a tiny focal checkpoint
from the real `lerobot-train`, then LeRobot's own `lerobot-rollout` with its RTC engine for a few seconds. A
`sitecustomize` (``rtc_dump_site``) records each `predict_action_chunk` call the engine's thread makes (the
leftover it passes, the delay, the chunk returned) without changing it: the chunks must be finite, whole
macro-trajectories, and every chunk after the first must continue the previous one (its first `inference_delay`
actions are the committed ones).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.subprocess  # lerobot-record, lerobot-train and lerobot-rollout
pytest.importorskip("mujoco")

BIN = Path(sys.executable).parent
SITE = Path(__file__).parent / "rtc_dump_site"
FPS, W, H = 10, 64, 48


def _env(tmp: Path, **extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env.update(HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1", WANDB_MODE="disabled", MUJOCO_GL="disable",
               HF_LEROBOT_CALIBRATION=str(tmp / "calibration"), HF_LEROBOT_HOME=str(tmp / "home"),
               PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1", **extra)
    return env


def _run(args: list[str], env: dict, log: Path, timeout: float) -> str:
    with log.open("w") as fh:
        rc = subprocess.run(args, env=env, stdout=fh, stderr=subprocess.STDOUT, timeout=timeout, check=False).returncode
    text = log.read_text(errors="replace")
    assert rc == 0, f"{Path(args[0]).name} exited {rc}:\n" + "\n".join(text.splitlines()[-40:])
    return text


def test_lerobot_rollout_rtc_drives_the_twin_with_focal_and_blends_chunks(tmp_path):
    from lerobot_focal.benchmarks.rollout_latency import record_dataset

    t0 = time.perf_counter()
    root = record_dataset(tmp_path / "data", W, H, FPS, episodes=2, seconds=2.0,
                          calibration_dir=tmp_path / "calibration" / "robots" / "ur10e")
    out = tmp_path / "train"
    _run([str(BIN / "lerobot-train"), "--policy.type=focal", "--policy.push_to_hub=false", "--policy.device=cpu",
          "--policy.use_images=false", "--policy.down_dims=[16,32,64]", "--dataset.repo_id=local/ur10e_rollout_bench",
          f"--dataset.root={root}", "--steps=3", "--batch_size=4", "--num_workers=0", "--save_freq=3",
          "--log_freq=3", "--wandb.enable=false", f"--output_dir={out}"],
         _env(tmp_path), tmp_path / "train.log", timeout=600)
    model = out / "checkpoints" / "last" / "pretrained_model"

    dump = tmp_path / "dump"
    env = _env(tmp_path, FOCAL_DUMP_RTC=str(dump),
               PYTHONPATH=os.pathsep.join(filter(None, [str(SITE), os.environ.get("PYTHONPATH")])))
    log = _run([str(BIN / "lerobot-rollout"), "--strategy.type=base", "--inference.type=rtc",
                "--inference.rtc.execution_horizon=8", "--inference.queue_threshold=8", f"--policy.path={model}",
                "--policy.device=cpu", "--robot.type=ur10e", "--robot.backend=sim", f"--robot.control_hz={FPS}",
                f"--robot.sim_camera_width={W}", f"--robot.sim_camera_height={H}", f"--fps={FPS}", "--duration=5",
                "--task=move the arm", "--play_sounds=false"],
               env, tmp_path / "rollout.log", timeout=300)
    assert "not supported by policy type" not in log
    assert "RTC inference thread started" in log  # LeRobot's RTC engine ran, not the sync one
    assert "focal RTC: chunk guided by the previous chunk's" in log  # ... and focal's guided step

    calls = [np.load(p) for p in sorted(dump.glob("call_*.npz"))]
    assert len(calls) >= 5, len(calls)
    for c in calls:
        assert c["chunk"].shape == (1, 12, 7)  # L = N·H = 12 actions of the twin's 7-d command
        assert np.isfinite(c["chunk"]).all()
    guided = [c for c in calls if c["prev"].size]
    assert len(guided) >= len(calls) - 1  # only the first chunk has nothing to continue
    blended = 0
    for c in guided:
        prev, delay, chunk = c["prev"], int(c["delay"]), c["chunk"][0]
        assert prev.shape == (8, 7)  # the engine's leftover, padded or cut to execution_horizon
        committed = int(np.flatnonzero(np.abs(prev).sum(axis=1) > 0).max(initial=-1)) + 1
        d = min(delay, committed)
        if d:
            # The actions executed while this chunk was computed are the previous chunk's, exactly.
            np.testing.assert_allclose(chunk[:d], prev[:d], atol=1e-5)
            blended += 1
    assert blended >= 3, [int(c["delay"]) for c in guided]
    print(f"rtc rollout test: {len(calls)} chunks, {blended} blended, {time.perf_counter() - t0:.0f} s")
