"""The record -> train -> deploy loop on the simulated UR-10e, through LeRobot's real console scripts.

Every step is a real subprocess of the installed CLI (``lerobot-record``, ``lerobot-train``, ``lerobot-rollout``)
that finds the plugin through LeRobot's own plugin discovery. The only stand-in is the gamepad: an SDL virtual
F710 attached inside the ``lerobot-record`` process by ``virtual_pad_site/sitecustomize.py`` (SDL virtual
joysticks exist only in the process that attaches them), read by the real focal_gamepad/pygame path.

LeRobot 0.6.1's ``lerobot-record`` has no ``--policy`` option any more (it says "use lerobot-rollout for policy
deployment"), so deployment is ``lerobot-rollout --strategy.type=base --policy.path=...``.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("pygame")

BIN = Path(sys.executable).parent
SITE = Path(__file__).parent / "virtual_pad_site"
REPO_ID = "local/ur10e_sim_demo"
FPS = 10
EPISODE_S = 2
ROBOT = ["--robot.type=ur10e", "--robot.backend=sim", f"--robot.control_hz={FPS}"]


def _env(tmp: Path, pad: bool) -> dict[str, str]:
    env = dict(os.environ)
    env.update(
        HF_HUB_OFFLINE="1",
        HF_DATASETS_OFFLINE="1",
        WANDB_MODE="disabled",
        HF_LEROBOT_CALIBRATION=str(tmp / "calibration"),
        HF_LEROBOT_HOME=str(tmp / "lerobot_home"),
        SDL_VIDEODRIVER="dummy",
        SDL_AUDIODRIVER="dummy",
        MUJOCO_GL="disable",
        PYTHONUNBUFFERED="1",
    )
    env.pop("DISPLAY", None)
    if pad:
        env["FOCAL_VIRTUAL_PAD"] = "1.0"
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(SITE), env.get("PYTHONPATH")]))
    return env


def _record_args(root: Path, episodes: int) -> list[str]:
    return [
        str(BIN / "lerobot-record"),
        *ROBOT,
        "--teleop.type=focal_gamepad",
        f"--dataset.repo_id={REPO_ID}",
        f"--dataset.root={root}",
        f"--dataset.fps={FPS}",
        f"--dataset.episode_time_s={EPISODE_S}",
        "--dataset.reset_time_s=0",
        f"--dataset.num_episodes={episodes}",
        "--dataset.push_to_hub=false",
        "--dataset.single_task=move the arm",
        "--play_sounds=false",
    ]


def _run(args: list[str], env: dict, log: Path, timeout: float) -> subprocess.CompletedProcess:
    with log.open("w") as fh:
        proc = subprocess.run(args, env=env, stdout=fh, stderr=subprocess.STDOUT, timeout=timeout, check=False)
    if proc.returncode != 0:
        pytest.fail(f"{Path(args[0]).name} exited {proc.returncode}; last lines:\n" + _tail(log))
    return proc


def _tail(log: Path, n: int = 40) -> str:
    return "\n".join(log.read_text(errors="replace").splitlines()[-n:])


def _load(root: Path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(REPO_ID, root=root)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("loop")
    root = tmp / "dataset"
    t0 = time.perf_counter()
    _run(_record_args(root, episodes=2), _env(tmp, pad=True), tmp / "record.log", timeout=240)
    return tmp, root, time.perf_counter() - t0


def test_record_with_virtual_gamepad_writes_a_valid_dataset(recorded):
    tmp, root, _ = recorded
    ds = _load(root)
    assert ds.num_episodes == 2
    assert ds.meta.robot_type == "ur10e"
    assert ds.meta.features["action"]["names"] == [
        "ee_x.vel", "ee_y.vel", "ee_z.vel", "ee_roll.vel", "ee_pitch.vel", "ee_yaw.vel", "gripper.pos"
    ]  # fmt: skip
    names = ds.meta.features["observation.state"]["names"]
    assert names[6:] == [f"ee_{a}.pos" for a in ("x", "y", "z", "roll", "pitch", "yaw")] + ["gripper.pos"]
    assert ds.meta.features["observation.images.front_depth"]["info"]["is_depth_map"] is True
    # ~EPISODE_S * FPS frames per episode (a slow host may drop a few, never add any).
    lengths = [int(e["length"]) for e in ds.meta.episodes]
    assert all(0.7 * EPISODE_S * FPS <= n <= EPISODE_S * FPS for n in lengths), lengths

    frames = [ds[i] for i in range(len(ds))]
    actions = np.stack([f["action"].numpy() for f in frames])
    states = np.stack([f["observation.state"].numpy() for f in frames])
    # The virtual pad holds the deadman and pushes the sticks: recorded commands are non-zero, bounded by the
    # teleop's speed (0.15 m/s x speed level 0.5), and the gripper command is the default "open".
    assert np.abs(actions[:, :2]).max() > 0.03
    assert np.abs(actions[:, :3]).max() <= 0.15 * 0.5 + 1e-6
    np.testing.assert_allclose(actions[:, 6], 1.0)
    # ... and the arm really followed them: over each episode the TCP moved the way it was commanded (+x).
    ep = np.array([int(f["episode_index"]) for f in frames])
    for e in (0, 1):
        cmd = actions[ep == e, :3].sum(axis=0) / FPS  # commanded displacement, m
        moved = states[ep == e][-1, 6:9] - states[ep == e][0, 6:9]
        assert cmd[0] > 0.05 and moved[0] > 0.5 * cmd[0], (cmd, moved)
        assert np.dot(cmd, moved) > 0, (cmd, moved)
    # Camera frames decode with the right shapes; depth comes back in millimetres.
    f = frames[len(frames) // 2]
    assert tuple(f["observation.images.front"].shape) == (3, 128, 128)
    depth_mm = f["observation.images.front_depth"].numpy()
    assert depth_mm.shape == (1, 128, 128) and 500 < np.median(depth_mm) < 3000


def test_recorded_depth_and_saved_intrinsics_give_a_pointcloud(recorded):
    """The stored depth (LeRobot's 12-bit depth video) + the intrinsics the robot saved are enough to rebuild
    the point cloud later: the table comes back as the plane z = 0 and the cube as a 4 cm tall blob."""
    from lerobot_focal.robots.ur10e.camera_info import depth_to_pointcloud, load_camera_infos

    tmp, root, _ = recorded
    infos = load_camera_infos(tmp / "calibration" / "robots" / "ur10e" / "ur10e_cameras.json")
    assert set(infos) == {"front"}
    depth = _load(root)[5]["observation.images.front_depth"].numpy()[0] / 1000.0  # mm -> m
    info = infos["front"]
    cloud = depth_to_pointcloud(
        depth, type(info)(**{**info.to_dict(), "depth_scale": 1.0}), (-1.1, -0.7, -0.05), (-0.2, 0.4, 0.8), 512
    )
    assert cloud.shape == (512, 3)
    table = cloud[cloud[:, 2] < 0.01]
    assert len(table) > 200 and np.percentile(np.abs(table[:, 2]), 90) < 5e-3
    cube = np.linalg.norm(cloud[:, :2] - np.array([-0.65, -0.05]), axis=1) < 0.03
    assert cube.any() and cloud[cube, 2].max() == pytest.approx(0.04, abs=0.01)


def test_ctrl_c_during_recording_keeps_saved_episodes(tmp_path):
    root = tmp_path / "dataset"
    log = tmp_path / "record.log"
    with log.open("w") as fh:
        proc = subprocess.Popen(
            _record_args(root, episodes=5), env=_env(tmp_path, pad=True), stdout=fh, stderr=subprocess.STDOUT
        )
    try:
        deadline = time.monotonic() + 180
        # "Recording episode 2" is logged after episodes 0 and 1 were saved; interrupt episode 2 halfway.
        while "Recording episode 2" not in log.read_text(errors="replace"):
            assert proc.poll() is None, _tail(log)
            assert time.monotonic() < deadline, _tail(log)
            time.sleep(0.2)
        time.sleep(EPISODE_S / 2)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    text = log.read_text(errors="replace")
    assert "KeyboardInterrupt" in text, _tail(log)
    assert re.search(r"UR10e disconnected after \d+ commands", text), _tail(log)  # the arm was stopped
    ds = _load(root)
    assert ds.num_episodes == 2  # the interrupted episode is dropped, the saved ones are intact
    assert len(ds) == sum(int(e["length"]) for e in ds.meta.episodes)
    for i in range(len(ds)):  # every frame, incl. both video streams, decodes
        item = ds[i]
        assert np.isfinite(item["action"].numpy()).all()
        assert item["observation.images.front"].shape == (3, 128, 128)


@pytest.mark.slow
def test_train_focal_then_rollout_drives_the_sim_arm(recorded, tmp_path):
    tmp, root, _ = recorded
    out = tmp_path / "train"
    # Depth stays in the dataset, but the policy is given RGB + state only (see docs/robot.md: LeRobot 0.6.1's
    # rollout hands uint16 depth to the normaliser, which cannot cast float stats to uint16).
    features = {
        "observation.state": {"type": "STATE", "shape": [13]},
        "observation.images.front": {"type": "VISUAL", "shape": [3, 128, 128]},
    }
    _run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=focal",
            "--policy.down_dims=[32,64,128]",
            "--policy.push_to_hub=false",
            "--policy.device=cpu",
            f"--policy.input_features={json.dumps(features)}",
            f"--dataset.repo_id={REPO_ID}",
            f"--dataset.root={root}",
            "--steps=10",
            "--batch_size=4",
            "--num_workers=0",
            "--save_freq=10",
            "--log_freq=5",
            "--wandb.enable=false",
            f"--output_dir={out}",
        ],
        _env(tmp_path, pad=False),
        tmp_path / "train.log",
        timeout=600,
    )
    model = out / "checkpoints" / "last" / "pretrained_model"
    assert (model / "model.safetensors").is_file()
    assert json.loads((model / "config.json").read_text())["type"] == "focal"

    log = tmp_path / "rollout.log"
    _run(
        [
            str(BIN / "lerobot-rollout"),
            "--strategy.type=base",
            f"--policy.path={model}",
            "--policy.device=cpu",
            *ROBOT,
            f"--fps={FPS}",
            "--duration=4",
            "--task=move the arm",
        ],
        _env(tmp_path, pad=False),
        log,
        timeout=300,
    )
    text = log.read_text(errors="replace")
    assert "Policy loaded: type=focal" in text
    m = re.search(r"UR10e disconnected after (\d+) commands \(commanded TCP path ([\d.]+) m\)", text)
    assert m, _tail(log)
    # The policy's commands reached the arm (plus rollout's 3 s return to the start pose at 50 Hz).
    assert int(m.group(1)) > 150 and float(m.group(2)) > 0.0, m.group(0)


def test_teleoperate_with_virtual_gamepad_moves_the_sim_arm(tmp_path):
    log = tmp_path / "teleop.log"
    args = [str(BIN / "lerobot-teleoperate"), *ROBOT[:2], "--teleop.type=focal_gamepad", "--fps=30", "--teleop_time_s=3"]
    _run(args, _env(tmp_path, pad=True), log, timeout=180)
    m = re.search(r"UR10e disconnected after (\d+) commands \(commanded TCP path ([\d.]+) m\)", log.read_text())
    assert m, _tail(log)
    assert int(m.group(1)) > 20 and float(m.group(2)) > 0.02, m.group(0)
