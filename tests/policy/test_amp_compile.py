"""LeRobot's precision and compile switches with focal, as real CLI processes (docs/compatibility.md):

* ``lerobot-train --policy.use_amp=true``: LeRobot 0.6.1 turns it into Accelerate's mixed precision, on a CPU
  bfloat16 autocast (``torch.get_autocast_dtype("cpu")``); ``lerobot-eval --policy.use_amp=true`` runs the policy
  inside ``torch.autocast``;
* ``lerobot-rollout --use_torch_compile=true`` wraps the policy's ``predict_action_chunk`` in ``torch.compile``
  (``--torch_compile_backend``, default inductor). ``lerobot-eval`` has no compile switch in 0.6.1.

The inductor rollout compiles for minutes on a 2-core CPU, so it is a slow test; the default one compiles with
dynamo's ``eager`` backend, which traces focal's chunk exactly as inductor's does and skips the code generation.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from tests.policy.helpers import small_policy

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
UR10E_STATE = {"observation.state": {"type": "STATE", "shape": [13]}}


def _run(cmd: list[str], cwd: Path, timeout: int = 600, **extra_env: str) -> str:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "WANDB_MODE": "disabled",
           "HF_LEROBOT_CALIBRATION": str(cwd / "calibration"), "PYTHONUNBUFFERED": "1", **extra_env}
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"{Path(cmd[0]).name} failed ({proc.returncode}):\n{log[-6000:]}"
    return log


def _train(dataset: Path, repo_id: str, out: Path, *args: str) -> tuple[Path, str]:
    log = _run([str(BIN / "lerobot-train"), f"--config_path={REPO / 'configs' / 'focal_cpu_state.json'}",
                f"--dataset.repo_id={repo_id}", f"--dataset.root={dataset}", f"--output_dir={out}",
                "--policy.push_to_hub=false", "--policy.device=cpu", "--steps=4", "--save_freq=4", "--log_freq=1",
                "--batch_size=4", "--num_workers=0", *args], cwd=out.parent)
    return out / "checkpoints" / "last" / "pretrained_model", log


def test_autocast_runs_focals_network_in_bfloat16_with_a_finite_loss():
    policy = small_policy().train()
    seen = []
    policy.model.velocity_net.register_forward_hook(lambda m, i, out: seen.append(out.dtype))
    batch = {"observation.state": torch.randn(4, 2, 9), "observation.pointcloud": torch.randn(4, 2, 64, 3),
             "action": torch.randn(4, 12, 3)}
    with torch.autocast(device_type="cpu"):  # what Accelerate's mixed precision does on a CPU
        loss, logs = policy.forward(batch)
    assert torch.bfloat16 in seen
    assert loss.dtype == torch.float32 and torch.isfinite(loss)
    loss.backward()
    grads = [p.grad for p in policy.model.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads)
    assert all(math.isfinite(v) for v in logs.values())
    # Acting under autocast (lerobot-eval --policy.use_amp=true): float32 actions, which numpy can take.
    policy.eval().reset()
    with torch.inference_mode(), torch.autocast(device_type="cpu"):
        action = policy.select_action({"observation.state": torch.randn(1, 9),
                                       "observation.pointcloud": torch.randn(1, 64, 3)})
    assert action.dtype == torch.float32 and torch.isfinite(action).all()


@pytest.fixture(scope="module")
def amp_metaworld_run(tmp_path_factory):
    pytest.importorskip("metaworld")
    tmp = tmp_path_factory.mktemp("amp")
    data = tmp / "data"
    _run([sys.executable, "-m", "lerobot_focal.datasets.making.collect", "--root", str(data), "--tasks", "reach",
          "--episodes", "1", "--until", "success", "--obs_types", "state,env_state"], cwd=tmp)
    ckpt, log = _train(data, "local/focal_metaworld", tmp / "train", "--policy.use_amp=true")
    return tmp, ckpt, log


@pytest.mark.subprocess
def test_lerobot_train_with_use_amp_trains_with_finite_losses(amp_metaworld_run):
    _, ckpt, log = amp_metaworld_run
    losses = [float(v) for v in re.findall(r"step:\d+ .*? loss:(\S+)", log)]
    assert len(losses) >= 4 and all(math.isfinite(v) for v in losses), losses
    train_cfg = json.loads((ckpt / "train_config.json").read_text())
    assert train_cfg["policy"]["use_amp"] is True and train_cfg["policy"]["device"] == "cpu"


@pytest.mark.subprocess
def test_lerobot_eval_with_use_amp_runs_the_amp_checkpoint(amp_metaworld_run):
    tmp, ckpt, _ = amp_metaworld_run
    out = tmp / "eval"
    _run([str(BIN / "lerobot-eval"), f"--policy.path={ckpt}", "--policy.use_amp=true", "--policy.device=cpu",
          "--env.type=focal_metaworld", "--env.task=reach", "--env.obs_type=state", "--env.env_state=true",
          "--env.episode_length=20", "--eval.n_episodes=1", "--eval.batch_size=1", f"--output_dir={out}"], cwd=tmp)
    overall = json.loads((out / "eval_info.json").read_text())["overall"]
    assert overall["n_episodes"] == 1 and 0.0 <= overall["pc_success"] <= 100.0


@pytest.fixture(scope="module")
def ur10e_checkpoint(tmp_path_factory):
    pytest.importorskip("mujoco")
    from lerobot_focal.benchmarks.rollout_latency import record_dataset

    tmp = tmp_path_factory.mktemp("compile")
    data = record_dataset(tmp / "data", width=64, height=48, fps=10, episodes=1, seconds=2.0,
                          calibration_dir=tmp / "calibration")
    ckpt, _ = _train(data, "local/ur10e_rollout_bench", tmp / "train", "--policy.use_env_state=false",
                     f"--policy.input_features={json.dumps(UR10E_STATE)}")
    return tmp, ckpt


@pytest.mark.slow  # ~1.5 min with its recorded dataset and training; use_amp's train and eval stay in the default suite
@pytest.mark.parametrize("backend", ["eager", "inductor"])
def test_lerobot_rollout_with_use_torch_compile_drives_the_twin(ur10e_checkpoint, backend):
    tmp, ckpt = ur10e_checkpoint
    log = _run([str(BIN / "lerobot-rollout"), "--strategy.type=base", f"--policy.path={ckpt}", "--policy.device=cpu",
                "--robot.type=ur10e", "--robot.backend=sim", "--robot.sim_camera_width=64",
                "--robot.sim_camera_height=48", "--robot.control_hz=10", "--fps=10", "--duration=4",
                "--task=move the arm", "--use_torch_compile=true", f"--torch_compile_backend={backend}"],
               cwd=tmp, timeout=1500, MUJOCO_GL="disable")  # the twin's camera ray-casts: no OpenGL
    assert "Policy loaded: type=focal" in log
    assert "torch.compile configured for predict_action_chunk" in log
    assert "Failed to configure torch.compile" not in log
    m = re.search(r"UR10e disconnected after (\d+) commands", log)
    assert m and int(m.group(1)) > 0, log[-3000:]
