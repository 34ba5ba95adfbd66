"""Multi-process training through LeRobot's own engine: `accelerate launch` + `lerobot-train --policy.type=focal`.

A real 2-process DDP run on this CPU (gloo backend) against a one-process run on the same data. The launch is
the one documented in docs/multi_gpu.md; on a machine without GPUs `--multi_gpu` still starts the processes
with torchrun, and `--policy.device=cpu` makes LeRobot's Accelerator use the CPU, hence gloo. (`accelerate
launch --cpu --num_processes=2` would start ONE process: accelerate's multi-CPU path needs mpirun.)

The launched script is tests/policy/accelerate_probe.py: LeRobot's `lerobot-train` entry point with a probe that
records, per rank and per optimizer step, a hash of the EMA and online weights and of the noise / times / data
each rank trained on. Nothing in the policy is changed for the test.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_focal.datasets.making.synthetic import SyntheticSpec, write_synthetic_dataset
from lerobot_focal.policy import FocalPolicy

from .accelerate_probe import sha

pytestmark = pytest.mark.slow  # three lerobot-train runs, ~2 minutes on 2 cores

BIN = Path(sys.executable).parent
PROBE = Path(__file__).with_name("accelerate_probe.py")
STEPS, RESUMED_STEPS = 4, 6

# The invocation under test (docs/multi_gpu.md). `--main_process_port` is added per run (a free port).
ACCELERATE_2_PROCESSES = [
    "--multi_gpu",
    "--num_processes=2",
    "--num_machines=1",
    "--mixed_precision=no",
    "--dynamo_backend=no",
]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(launcher: list[str], args: list[str], *, tmp: Path, probe_dir: Path) -> str:
    env = {
        **os.environ,
        "OMP_NUM_THREADS": "1",  # 2 processes on a small shared machine
        "HF_HUB_OFFLINE": "1",
        "WANDB_MODE": "disabled",
        # A private HF_HOME: no ~/.cache/huggingface/accelerate/default_config.yaml of the user's leaks in.
        "HF_HOME": str(tmp / "hf_home"),
        "FOCAL_PROBE_DIR": str(probe_dir),
    }
    # Own session: on a timeout the launcher AND its worker processes are killed, none is left behind.
    proc = subprocess.Popen(
        [*launcher, str(PROBE), *args], cwd=tmp, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, start_new_session=True,
    )
    try:
        log, _ = proc.communicate(timeout=300)  # ~40 s normally
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        log, _ = proc.communicate()
        raise AssertionError(f"{' '.join(launcher)} lerobot-train timed out:\n{log[-8000:]}") from None
    if proc.returncode != 0:
        raise AssertionError(f"{' '.join(launcher)} lerobot-train failed ({proc.returncode}):\n{log[-8000:]}")
    return log


def _accelerate(port: int) -> list[str]:
    return [str(BIN / "accelerate"), "launch", *ACCELERATE_2_PROCESSES, f"--main_process_port={port}"]


def _records(probe_dir: Path, rank: int, kind: str) -> list[dict]:
    lines = (probe_dir / f"rank{rank}.jsonl").read_text().splitlines()
    return [r for r in map(json.loads, lines) if r["kind"] == kind]


def _logged_losses(log: str) -> dict[int, float]:
    return {int(s): float(v) for s, v in re.findall(r"step:(\d+) smpl:\S+ .*?\bloss:(\S+)", log)}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("accelerate")
    root = tmp / "dataset"
    write_synthetic_dataset(root, SyntheticSpec(num_episodes=3, episode_length=20, num_points=64))
    common = [
        "--policy.type=focal",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--policy.down_dims=[16,32,64]",
        "--wandb.enable=false",
        "--dataset.repo_id=local/focal_synthetic",
        f"--dataset.root={root}",
        f"--steps={STEPS}",
        "--save_freq=2",
        "--log_freq=1",
        "--batch_size=4",
        "--num_workers=0",
    ]
    one = _run([sys.executable], [*common, f"--output_dir={tmp / 'one'}"], tmp=tmp, probe_dir=tmp / "probe_one")
    two = _run(_accelerate(_free_port()), [*common, f"--output_dir={tmp / 'two'}"], tmp=tmp,
               probe_dir=tmp / "probe_two")
    train_cfg = tmp / "two" / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    resumed = _run(
        _accelerate(_free_port()),
        ["--resume=true", f"--config_path={train_cfg}", f"--steps={RESUMED_STEPS}"],
        tmp=tmp,
        probe_dir=tmp / "probe_resumed",
    )
    return {"tmp": tmp, "one": one, "two": two, "resumed": resumed}


def test_two_processes_ran_with_gloo(runs):
    log = runs["two"]
    assert "Effective batch size: 4 x 2 = 8" in log
    assert "Effective batch size: 4 x 1 = 4" in runs["one"]
    assert "End of training" in log and "End of training" in runs["resumed"]
    for rank in (0, 1):
        assert len(_records(runs["tmp"] / "probe_two", rank, "update")) == STEPS
    # Each rank trained on its own shard of the data.
    data = [[r["m1"] for r in _records(runs["tmp"] / "probe_two", rank, "loss")] for rank in (0, 1)]
    assert all(a != b for a, b in zip(*data, strict=True))


def test_same_step_count_and_finite_losses(runs):
    tmp = runs["tmp"]
    for name in ("one", "two"):
        for step in ("000002", "000004"):
            assert (tmp / name / "checkpoints" / step / "pretrained_model" / "model.safetensors").is_file()
        # (Not "last": the resume test below moves the 2-process run's "last" on to step 6.)
        step_file = tmp / name / "checkpoints" / f"{STEPS:06d}" / "training_state" / "training_step.json"
        state = json.loads(step_file.read_text())
        assert state["step"] == STEPS
        losses = _logged_losses(runs[name])
        assert sorted(losses) == list(range(1, STEPS + 1)), losses
        assert all(math.isfinite(v) for v in losses.values())
    for rank in (0, 1):
        assert all(math.isfinite(r["loss"]) for r in _records(tmp / "probe_two", rank, "loss"))
    # The 2-process run starts exactly where the 1-process one does: same initial weights on every rank,
    # rank 0 gets the first batch the single process gets, so the first loss matches bit for bit.
    assert _records(tmp / "probe_two", 0, "loss")[0]["loss"] == _records(tmp / "probe_one", 0, "loss")[0]["loss"]


def test_ema_updated_once_per_step_and_equal_across_ranks(runs):
    tmp = runs["tmp"]
    for probe, steps in (("probe_two", range(1, STEPS + 1)), ("probe_resumed", range(STEPS + 1, RESUMED_STEPS + 1))):
        rank0, rank1 = (_records(tmp / probe, rank, "update") for rank in (0, 1))
        assert [r["ema_step"] for r in rank0] == [r["ema_step"] for r in rank1] == list(steps)
        assert [r["ema"] for r in rank0] == [r["ema"] for r in rank1]
        assert [r["online"] for r in rank0] == [r["online"] for r in rank1]
    # The EMA has left the online weights once the warm-up (decay 0 for the first updates) is over.
    last = _records(tmp / "probe_two", 0, "update")[-1]
    assert last["ema"] != last["online"]


def test_checkpoint_from_main_process_loads_with_the_ranks_ema(runs):
    tmp = runs["tmp"]
    for run, probe, step in (("two", "probe_two", STEPS), ("two", "probe_resumed", RESUMED_STEPS)):
        model_dir = tmp / run / "checkpoints" / f"{step:06d}" / "pretrained_model"
        policy = FocalPolicy.from_pretrained(model_dir)
        assert int(policy.ema_step) == step
        last = _records(tmp / probe, 0, "update")[-1]
        assert last["ema_step"] == step
        assert sha(policy.ema_model.state_dict().values()) == last["ema"]
        assert sha(policy.model.state_dict().values()) == last["online"]


def test_resume_with_two_processes(runs):
    tmp, log = runs["tmp"], runs["resumed"]
    assert "Effective batch size: 4 x 2 = 8" in log
    assert "Resuming data order at epoch 0, sample 32" in log  # 4 steps x 4 samples x 2 processes
    state = json.loads((tmp / "two" / "checkpoints" / "last" / "training_state" / "training_step.json").read_text())
    assert state["step"] == RESUMED_STEPS
    losses = _logged_losses(log)
    assert sorted(losses) == [5, 6] and all(math.isfinite(v) for v in losses.values())


def test_each_rank_draws_its_own_noise_and_times(runs):
    ranks = [_records(runs["tmp"] / "probe_two", rank, "loss") for rank in (0, 1)]
    for a, b in zip(*ranks, strict=True):
        assert a["m0"] != b["m0"]
        assert a["tau"] != b["tau"]
