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
import torch

from lerobot_focal.robots.ur10e.twin.scene import crop_flags

pytestmark = pytest.mark.subprocess  # lerobot-record / -train / -rollout / -teleoperate on the twin

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


def _record_args(root: Path, episodes: int, robot: list[str] = ROBOT) -> list[str]:
    return [
        str(BIN / "lerobot-record"),
        *robot,
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


def _train(root: Path, out: Path, tmp_path: Path, *policy_args: str, steps: int, log_freq: int) -> Path:
    """A small `lerobot-train` run of focal on the recorded dataset; returns the last checkpoint."""
    args = [
        str(BIN / "lerobot-train"), "--policy.type=focal", "--policy.push_to_hub=false", "--policy.device=cpu",
        *policy_args, f"--dataset.repo_id={REPO_ID}", f"--dataset.root={root}", f"--steps={steps}",
        "--batch_size=4", "--num_workers=0", f"--save_freq={steps}", f"--log_freq={log_freq}",
        "--wandb.enable=false", f"--output_dir={out}",
    ]
    _run(args, _env(tmp_path, pad=False), tmp_path / "train.log", timeout=600)
    return out / "checkpoints" / "last" / "pretrained_model"


def _rollout(model: Path, robot: list[str], tmp_path: Path, log: Path) -> str:
    """`lerobot-rollout` of a checkpoint on the arm for 4 s; returns its log."""
    args = [str(BIN / "lerobot-rollout"), "--strategy.type=base", f"--policy.path={model}", "--policy.device=cpu",
            *robot, f"--fps={FPS}", "--duration=4", "--task=move the arm"]
    _run(args, _env(tmp_path, pad=False), log, timeout=300)
    return log.read_text(errors="replace")


def wait_for_episode(log: Path, proc: subprocess.Popen, episode: int, timeout_s: float) -> None:
    """Wait (bounded) until `lerobot-record` logs that it records `episode` (the ones before it are saved)."""
    deadline = time.monotonic() + timeout_s
    while f"Recording episode {episode}" not in log.read_text(errors="replace"):
        assert proc.poll() is None, _tail(log)
        assert time.monotonic() < deadline, _tail(log)
        time.sleep(0.2)


def assert_frames_match_their_timestamps(ds, frames: list) -> None:
    """What a recording must contain whatever the machine's speed: per episode, frames numbered 0..n-1 with
    timestamps n / fps, none beyond the episode's time (a loaded host records fewer frames, never more)."""
    lengths = [int(e["length"]) for e in ds.meta.episodes]
    assert len(frames) == sum(lengths)
    ep = np.array([int(f["episode_index"]) for f in frames])
    for e, n in enumerate(lengths):
        assert 2 <= n <= EPISODE_S * FPS, lengths
        idx = np.array([int(f["frame_index"]) for f in frames])[ep == e]
        ts = np.array([float(f["timestamp"]) for f in frames])[ep == e]
        np.testing.assert_array_equal(idx, np.arange(n))
        np.testing.assert_allclose(ts, idx / ds.fps, atol=1e-4)


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
    frames = [ds[i] for i in range(len(ds))]
    assert_frames_match_their_timestamps(ds, frames)
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
        # "Recording episode 2" is logged after episodes 0 and 1 were saved; interrupt episode 2 halfway.
        wait_for_episode(log, proc, 2, timeout_s=180)
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


def test_focal_trains_on_recorded_images_with_lerobots_image_transforms(recorded, tmp_path):
    """The paper's robot saw RGB through random crops and colour jitter. LeRobot's dataset image transforms
    (`--dataset.image_transforms.enable=true`: colour jitter, sharpness, affine) and focal's own random crop
    train together in a real `lerobot-train` on the recorded sim-arm dataset."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.transforms.transforms import ImageTransforms, ImageTransformsConfig

    _, root, _ = recorded
    model = _train(
        root, tmp_path / "train", tmp_path, "--policy.down_dims=[16,32]", "--policy.spatial_softmax_num_keypoints=8",
        "--policy.use_images=true", "--policy.crop_shape=[112,112]", "--policy.crop_is_random=true",
        "--dataset.image_transforms.enable=true", "--dataset.image_transforms.max_num_transforms=3",
        steps=3, log_freq=1,
    )
    train_cfg = json.loads((model / "train_config.json").read_text())
    assert train_cfg["dataset"]["image_transforms"]["enable"] is True
    cfg = json.loads((model / "config.json").read_text())
    assert cfg["use_images"] is True and cfg["crop_shape"] == [112, 112] and cfg["crop_is_random"] is True
    losses = [float(x) for x in re.findall(r"\bloss:([0-9.]+)", (tmp_path / "train.log").read_text())]
    assert len(losses) == 3 and all(np.isfinite(losses))
    # The transforms really act on the frames the policy trains on: the same item read twice differs.
    ds = LeRobotDataset(REPO_ID, root=root, image_transforms=ImageTransforms(
        ImageTransformsConfig(enable=True, max_num_transforms=3)))
    a, b = ds[3]["observation.images.front"], ds[3]["observation.images.front"]
    assert a.shape == (3, 128, 128) and not torch.equal(a, b)


@pytest.mark.slow
def test_train_focal_then_rollout_drives_the_sim_arm(recorded, tmp_path):
    tmp, root, _ = recorded
    out = tmp_path / "train"
    # RGB + state, with the input features listed explicitly; depth stays in the dataset and reaches the
    # preprocessor at rollout as raw uint16, which focal's normaliser leaves alone. The point-cloud variant
    # (depth -> observation.pointcloud in the preprocessor) is the next test.
    features = {
        "observation.state": {"type": "STATE", "shape": [13]},
        "observation.images.front": {"type": "VISUAL", "shape": [3, 128, 128]},
    }
    model = _train(root, out, tmp_path, "--policy.down_dims=[32,64,128]",
                   f"--policy.input_features={json.dumps(features)}", steps=10, log_freq=5)
    assert (model / "model.safetensors").is_file()
    assert json.loads((model / "config.json").read_text())["type"] == "focal"

    log = tmp_path / "rollout.log"
    text = _rollout(model, ROBOT, tmp_path, log)
    assert "Policy loaded: type=focal" in text
    m = re.search(r"UR10e disconnected after (\d+) commands \(commanded TCP path ([\d.]+) m\)", text)
    assert m, _tail(log)
    # The policy's commands reached the arm (plus rollout's 3 s return to the start pose at 50 Hz).
    assert int(m.group(1)) > 150 and float(m.group(2)) > 0.0, m.group(0)


DUMP_SITE = Path(__file__).parent / "pointcloud_dump_site"
DEPTH_KEY = "observation.images.front_depth"
CROP = crop_flags()  # the twin's table-top box (twin/scene.TABLE_TOP_BOX)


def _chamfer(a: np.ndarray, b: np.ndarray) -> float:
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    return float(max(d.min(1).mean(), d.min(0).mean()))


@pytest.mark.slow
def test_focal_pointcloud_from_depth_trains_and_rolls_out_with_the_same_clouds(recorded, tmp_path):
    """lerobot-train --policy.depth_cloud.from_depth on the recorded sim dataset (depth video; the cameras.json
    the robot wrote on connect is found from the dataset's robot type, with nothing copied by hand) gives a focal
    policy whose inputs include observation.pointcloud; lerobot-rollout --policy.path then builds that cloud
    from the robot's live uint16 depth with the checkpoint's own step. The clouds fed at rollout match the ones
    the saved step computes from the same frames once LeRobot has stored them as depth video and decoded them
    (the training path)."""
    import shutil

    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.processor.converters import batch_to_transition, transition_to_batch
    from safetensors.torch import load_file

    from lerobot_focal.policy.processor_focal import DepthToPointCloudProcessorStep

    tmp, recorded_root, _ = recorded
    root = tmp_path / "dataset"
    shutil.copytree(recorded_root, root)
    # Training on the machine that recorded: its calibration folder holds the file the robot wrote on connect.
    shutil.copytree(tmp / "calibration", tmp_path / "calibration")
    cameras = tmp_path / "calibration" / "robots" / "ur10e" / "ur10e_cameras.json"
    assert not (root / "meta" / "cameras.json").exists()
    out = tmp_path / "train"
    model = _train(root, out, tmp_path, "--policy.down_dims=[32,64,128]", "--policy.use_images=false",
                   f"--policy.depth_cloud.from_depth={DEPTH_KEY}", CROP[0],
                   CROP[1], steps=6, log_freq=3)
    config = json.loads((model / "config.json").read_text())
    assert config["input_features"]["observation.pointcloud"] == {"type": "STATE", "shape": [512, 3]}
    assert config["depth_cloud"]["from_depth"] == DEPTH_KEY
    weights = load_file(model / "model.safetensors")
    assert any(".pointcloud." in k for k in weights), "the policy has no point-cloud encoder"
    saved = json.loads((model / "policy_preprocessor.json").read_text())
    names = [s.get("registry_name") for s in saved["steps"]]
    assert names.index("focal_depth_to_pointcloud") < names.index("normalizer_processor")
    step_cfg = saved["steps"][names.index("focal_depth_to_pointcloud")]["config"]
    assert step_cfg["camera_info"]["fx"] == pytest.approx(json.loads(cameras.read_text())["front"]["fx"])

    dump = tmp_path / "dump"
    env = _env(tmp_path, pad=False)
    env["FOCAL_DUMP_POINTCLOUDS"] = str(dump)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(DUMP_SITE), env.get("PYTHONPATH")]))
    rollout_root = tmp_path / "rollout"
    log = tmp_path / "rollout.log"
    _run(
        [
            str(BIN / "lerobot-rollout"),
            "--strategy.type=episodic",
            f"--policy.path={model}",
            "--policy.device=cpu",
            *ROBOT,
            f"--fps={FPS}",
            "--dataset.repo_id=local/rollout_ur10e_pc",
            f"--dataset.root={rollout_root}",
            "--dataset.no_stamp=true",
            f"--dataset.fps={FPS}",
            "--dataset.episode_time_s=3",
            "--dataset.reset_time_s=0",
            "--dataset.num_episodes=1",
            "--dataset.single_task=move the arm",
            "--dataset.push_to_hub=false",
            "--play_sounds=false",
        ],
        env,
        log,
        timeout=300,
    )
    text = log.read_text(errors="replace")
    assert "Policy loaded: type=focal" in text
    m = re.search(r"UR10e disconnected after (\d+) commands", text)
    assert m and int(m.group(1)) > 10, _tail(log)

    # What the step saw at rollout: the robot's raw uint16 depth, batched by prepare_observation_for_inference.
    calls = [np.load(f) for f in sorted(dump.glob("call_*.npz"))]
    assert len(calls) >= 10, _tail(log)
    for c in calls:
        assert c["depth"].dtype == np.uint16 and c["depth"].shape == (1, 1, 128, 128)
        assert c["cloud"].shape == (1, 512, 3)
    live_depth = np.stack([c["depth"][0, 0].astype(np.float32) for c in calls])

    # The training path on the same frames: the rollout dataset's decoded depth video, in the (B, n_obs, 1, H, W)
    # float layout of a training batch, through the step reloaded from the checkpoint.
    pre = PolicyProcessorPipeline.from_pretrained(
        model, config_filename="policy_preprocessor.json", to_transition=batch_to_transition,
        to_output=transition_to_batch,
    )
    step = next(s for s in pre.steps if isinstance(s, DepthToPointCloudProcessorStep))
    ds = _load_any("local/rollout_ur10e_pc", rollout_root)
    assert 10 <= len(ds) <= len(calls)
    distances = []
    for i in range(len(ds)):
        decoded = ds[i][DEPTH_KEY]  # float32 (1, H, W) mm
        assert decoded.dtype == torch.float32
        err = np.abs(live_depth - decoded.numpy()[0]).mean(axis=(1, 2))
        j = int(err.argmin())  # the live frame this dataset frame was recorded from
        assert err[j] < 5.0, err[j]  # mean mm: codec error only
        cloud = step.depth_to_points(decoded[None, None])
        assert cloud.shape == (1, 1, 512, 3)
        distances.append(_chamfer(cloud[0, 0], calls[j]["cloud"][0]))
    # The live cloud is the step's output for that raw frame, bit for bit ...
    np.testing.assert_array_equal(step.depth_to_points(calls[0]["depth"]), calls[0]["cloud"])
    # ... and the 12-bit depth video (~1.4 mm mean depth error at 1-2 m) moves FPS's subset by well under a
    # centimetre (measured: 0.35 mm mean Chamfer distance, 0.41 mm max, between 512-point clouds ~5 cm apart).
    assert np.mean(distances) < 0.002 and np.max(distances) < 0.005, distances


def _load_any(repo_id: str, root: Path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(repo_id, root=root)


def test_teleoperate_with_virtual_gamepad_moves_the_sim_arm(tmp_path):
    log = tmp_path / "teleop.log"
    args = [str(BIN / "lerobot-teleoperate"), *ROBOT[:2], "--teleop.type=focal_gamepad", "--fps=30",
            "--teleop_time_s=3"]
    _run(args, _env(tmp_path, pad=True), log, timeout=180)
    m = re.search(r"UR10e disconnected after (\d+) commands \(commanded TCP path ([\d.]+) m\)", log.read_text())
    assert m, _tail(log)
    assert int(m.group(1)) > 20 and float(m.group(2)) > 0.02, m.group(0)
