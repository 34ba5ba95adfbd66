"""LeRobot's own async robot_client drives the UR-10e twin through `lerobot-focal-policy-server`, on loopback.

Real processes throughout: the twin records a short scripted dataset (colour + depth, `cameras.json` in
`meta/`), `lerobot-train` trains a tiny focal on state + RGB + a point cloud made from depth by its own
preprocessor step (deterministic chunks: `inference_noise_scale=0`), the installed `lerobot-focal-policy-server`
serves it and `python -m lerobot.async_inference.robot_client --robot.type=ur10e --robot.backend=sim` runs the
arm. A test-only sitecustomize (tests/deploy/async_dump_site) records the chunks in the server and the
observations and commands in the client, so the test checks that

* every action the arm executed is the server's action for that step;
* each chunk is what `lerobot-rollout`'s synchronous engine computes from the same two robot observations (the
  frames after f-1 and f executed actions), built from the client's raw observations by LeRobot's own code;
* the joints moved;

and that a checkpoint needing an input the robot does not send is refused with a message in the client's log.
"""

import json
import os
import pickle
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.subprocess  # the policy server, LeRobot's robot_client, lerobot-train
pytest.importorskip("grpc", reason="the async extra: pip install -e '.[async]'")
pytest.importorskip("mujoco")

from lerobot_focal.robots.ur10e.twin.scene import crop_flags  # noqa: E402
from tests.deploy.helpers import JOINTS, random_checkpoint  # noqa: E402

BIN = Path(sys.executable).parent
SITE = Path(__file__).parent / "async_dump_site"
FPS = 10
WIDTH = HEIGHT = 96
DEPTH_KEY = "observation.images.front_depth"
CROP = crop_flags()  # the twin's table-top box (twin/scene.TABLE_TOP_BOX)
CHUNKS = 10  # chunks to serve before the client is stopped


def _env(tmp: Path, **extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env.update(HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1", WANDB_MODE="disabled", MUJOCO_GL="disable",
               HF_LEROBOT_CALIBRATION=str(tmp / "calibration"), HF_LEROBOT_HOME=str(tmp / "lerobot_home"),
               PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1", **extra)
    if any(k.startswith("FOCAL_ASYNC_DUMP") for k in extra):
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(SITE), env.get("PYTHONPATH")]))
    return env


def _tail(log: Path, n: int = 40) -> str:
    return "\n".join(log.read_text(errors="replace").splitlines()[-n:])


def _wait_for(log: Path, proc: subprocess.Popen, pattern: str, timeout_s: float, count: int = 1) -> None:
    deadline = time.monotonic() + timeout_s
    while len(re.findall(pattern, log.read_text(errors="replace"))) < count:
        assert proc.poll() is None, f"exited {proc.returncode}:\n" + _tail(log)
        assert time.monotonic() < deadline, f"no {pattern!r} after {timeout_s} s:\n" + _tail(log)
        time.sleep(0.2)


def _interrupt(proc: subprocess.Popen, timeout_s: float) -> None:
    """Ctrl-C, as a user stops the client and the server; killed if it has not exited within the timeout."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A dataset recorded on the twin and a tiny focal trained on it by `lerobot-train`."""
    from lerobot_focal.benchmarks.rollout_latency import record_dataset

    tmp = tmp_path_factory.mktemp("async")
    root = record_dataset(tmp / "dataset", WIDTH, HEIGHT, FPS, episodes=2, seconds=2.0,
                          calibration_dir=tmp / "calibration")
    out = tmp / "train"
    args = [
        str(BIN / "lerobot-train"), "--policy.type=focal", "--policy.push_to_hub=false", "--policy.device=cpu",
        "--policy.down_dims=[16,32]", "--policy.use_images=true", "--policy.spatial_softmax_num_keypoints=8",
        f"--policy.depth_cloud.from_depth={DEPTH_KEY}", CROP[0],
        CROP[1], "--policy.inference_noise_scale=0",
        "--dataset.repo_id=local/ur10e_rollout_bench", f"--dataset.root={root}", "--steps=3", "--batch_size=4",
        "--num_workers=0", "--save_freq=3", "--log_freq=3", "--wandb.enable=false", f"--output_dir={out}",
    ]
    log = tmp / "train.log"
    with log.open("w") as fh:
        rc = subprocess.run(args, env=_env(tmp), stdout=fh, stderr=subprocess.STDOUT, timeout=600).returncode
    assert rc == 0, _tail(log)
    return tmp, root, out / "checkpoints" / "last" / "pretrained_model"


@pytest.fixture(scope="module")
def server(trained):
    """The installed `lerobot-focal-policy-server`, recording its chunks; yields (port, log, dump dir)."""
    tmp = trained[0]
    port, log, dump = _free_port(), tmp / "server.log", tmp / "server_dump"
    with log.open("w") as fh:
        proc = subprocess.Popen(
            [str(BIN / "lerobot-focal-policy-server"), "--host=127.0.0.1", f"--port={port}", f"--fps={FPS}"],
            env=_env(tmp, FOCAL_ASYNC_DUMP_SERVER=str(dump)), stdout=fh, stderr=subprocess.STDOUT, cwd=tmp,
        )
    try:
        _wait_for(log, proc, r"PolicyServer started on 127\.0\.0\.1", timeout_s=180)
        yield port, log, dump, proc
    finally:
        _interrupt(proc, timeout_s=20)


def _client(tmp: Path, port: int, model: Path, log: Path, **env: str) -> subprocess.Popen:
    """LeRobot's robot_client on the twin, as a user runs it (the README's command)."""
    args = [
        sys.executable, "-m", "lerobot.async_inference.robot_client", "--robot.type=ur10e", "--robot.backend=sim",
        f"--robot.control_hz={FPS}", f"--robot.sim_camera_width={WIDTH}", f"--robot.sim_camera_height={HEIGHT}",
        "--task=move the arm", f"--server_address=127.0.0.1:{port}", "--policy_type=focal",
        f"--pretrained_name_or_path={model}", "--policy_device=cpu", "--actions_per_chunk=4",
        "--chunk_size_threshold=0.5", "--aggregate_fn_name=latest_only", f"--fps={FPS}",
    ]
    with log.open("w") as fh:
        return subprocess.Popen(args, env=_env(tmp, **env), stdout=fh, stderr=subprocess.STDOUT, cwd=tmp)


def _records(path: Path) -> list:
    out = []
    with path.open("rb") as fh:
        while True:
            try:
                out.append(pickle.load(fh))
            except EOFError:
                return out


def _sent_frame(got: dict, raws: list[dict], features: dict) -> dict:
    """The frame, built as LeRobot builds it, of the one observation in `raws` the server's frame `got` equals."""
    from lerobot.utils.feature_utils import build_dataset_frame

    frames = [build_dataset_frame(features, raw, prefix="observation") for raw in raws]
    for frame in frames:
        if set(frame) == set(got) and all(np.array_equal(got[k], frame[k]) for k in frame):
            return frame
    closest = min(frames, key=lambda fr: float(np.abs(got["observation.state"] - fr["observation.state"]).max()))
    for key in closest:  # the assertion names the key and the difference
        np.testing.assert_array_equal(got[key], closest[key], err_msg=key)
    raise AssertionError(f"the server's frame is none of the {len(raws)} observations sent after that step")


def _sync_chunk(engine, frames: list[dict]) -> np.ndarray:
    """`lerobot-rollout`'s engine after frames (a, b): fed a for a whole chunk, then b; the 4 actions from b."""
    engine.reset()
    a, b = frames
    actions = [engine.get_action(dict(f)) for f in [a] * 4 + [b] * 4]
    return np.stack([x.numpy() for x in actions[4:]])


def test_lerobots_robot_client_drives_the_twin_through_the_server(trained, server):
    tmp, root, model = trained
    port, server_log, server_dump, _ = server
    client_dump, log = tmp / "client_dump", tmp / "client.log"
    proc = _client(tmp, port, model, log, FOCAL_ASYNC_DUMP_CLIENT=str(client_dump))
    try:
        _wait_for(server_log, proc, r"Chunk of 4 actions in", timeout_s=180, count=CHUNKS)
    finally:
        _interrupt(proc, timeout_s=30)
    text = log.read_text(errors="replace")
    m = re.search(r"UR10e disconnected after (\d+) commands", text)
    assert m and int(m.group(1)) >= 3 * CHUNKS, _tail(log)
    assert "Error receiving actions" not in text.split("UR10e disconnected")[0], _tail(log)  # until stopped
    server_text = server_log.read_text(errors="replace")
    assert "observation.images.front_depth <- front_depth" in server_text  # the depth the cloud is made from
    assert "2 observation frames per chunk" in server_text
    ms = [float(x) for x in re.findall(r"Chunk of 4 actions in ([\d.]+) ms", server_text)]
    print(f"\nserver: {len(ms)} chunks, median {np.median(ms):.1f} ms, max {max(ms):.1f} ms per chunk")

    chunks = [pickle.loads(p.read_bytes()) for p in sorted(server_dump.glob("chunk_*.pkl"))]
    records = _records(client_dump / "robot.pkl")
    observations = [(r[1], r[2]) for r in records if r[0] == "obs"]
    executed = [(r[1], r[2]) for r in records if r[0] == "action"]
    assert len(chunks) >= CHUNKS and len(executed) >= 3 * CHUNKS

    # Every command the arm got is the server's action for its timestep (LeRobot's client, latest_only), in
    # order. A timestep may repeat: LeRobot's client marks an action done only after sending it, so a chunk that
    # arrives meanwhile queues that action again (its race, seen on a loaded CPU); none is skipped.
    timesteps = [t for _, t in executed]
    assert timesteps[0] == 0 and all(b - a in (0, 1) for a, b in zip(timesteps, timesteps[1:], strict=False)), timesteps
    names = list(executed[0][0])
    served: dict[int, list[np.ndarray]] = {}
    for c in chunks:
        for t, a in zip(c["timesteps"], c["actions"], strict=True):
            served.setdefault(t, []).append(a)
    for action, t in executed:
        vec = np.array([action[n] for n in names], dtype=np.float32)
        assert t in served, f"step {t} was executed but no chunk holds it (served: {sorted(served)})"
        assert min(np.abs(vec - s).max() for s in served[t]) < 1e-6, (t, vec, served[t])
    print(f"client: {len(executed)} actions, {len(executed) - len(set(timesteps))} sent twice")

    # The joints moved.
    joints = np.array([[raw[j] for j in JOINTS] for _, raw in observations])
    assert np.abs(joints[-1] - joints[0]).max() > 0.01, joints[[0, -1]]

    # Each chunk: frames f-1 and f (the observations taken after the actions up to timesteps f-2 and f-1), and
    # the actions lerobot-rollout's engine computes from those raw observations (LeRobot's build_dataset_frame).
    # While no new action arrives the client sends several observations of the same frame (the held arm's state
    # moves by ~1e-19 between them); the server's frame must be exactly one of them.
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.policies import make_pre_post_processors
    from lerobot.rollout.inference.sync import SyncInferenceEngine

    from lerobot_focal.policy import FocalPolicy

    torch.set_num_threads(1)
    sent_at: dict[int, list[dict]] = {}
    for n, raw in observations:
        sent_at.setdefault(n, []).append(raw)
    features = LeRobotDatasetMetadata("local/ur10e_rollout_bench", root=root).features
    policy = FocalPolicy.from_pretrained(model)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(model))
    engine = SyncInferenceEngine(policy, pre, post, features, features["action"]["names"], "move the arm", "cpu",
                                 "ur10e")
    stacked = 0
    for c in chunks[:CHUNKS]:
        f = c["frame"]
        assert c["timesteps"] == list(range(f, f + 4))
        frames = [_sent_frame(got, sent_at[n], features)
                  for got, n in zip(c["frames"], (max(f - 1, 0), f), strict=True)]
        np.testing.assert_allclose(np.stack(c["actions"]), _sync_chunk(engine, frames), atol=1e-4, rtol=1e-4)
        stacked += f > 0 and not np.array_equal(frames[0]["observation.state"], frames[1]["observation.state"])
    assert stacked >= CHUNKS // 2, "the windows were copies of one frame"


def test_a_checkpoint_needing_an_input_the_robot_does_not_send_fails_the_client_loudly(trained, server, tmp_path):
    tmp = trained[0]
    port, server_log, _, _ = server
    model = random_checkpoint(tmp_path / "needs_cube" / "pretrained_model",
                              env_names=["cube_x.pos", "cube_y.pos", "cube_z.pos"])
    log = tmp_path / "client.log"
    proc = _client(tmp, port, model, log)
    try:
        proc.wait(timeout=180)  # LeRobot's client gives up by itself when the set-up is refused
    finally:
        _interrupt(proc, timeout_s=10)
    text = log.read_text(errors="replace")
    assert "Failed to connect to policy server" in text and "StatusCode.INVALID_ARGUMENT" in text, _tail(log)
    assert "'observation.environment_state': the robot sends no ['cube_x.pos', 'cube_y.pos', 'cube_z.pos']" in text
    assert re.search(r"UR10e disconnected after 0 commands", text), _tail(log)
    assert "Policy set-up failed" in server_log.read_text(errors="replace")
    assert json.loads((model / "config.json").read_text())["use_env_state"] is True
