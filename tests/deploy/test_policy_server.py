"""`lerobot-focal-policy-server` in this process, spoken to over loopback gRPC with LeRobot's own stub and
messages (what LeRobot's robot_client sends): inputs built from the raw robot observation by the training
dataset's names, the two-frame history, the first action of a chunk, and the errors the client gets.

The checkpoint is a random-weights focal with state + environment state (written with the plugin's own
save_pretrained and processor factory, deterministic chunks); the robot is the UR-10e twin's feature set.
The end-to-end run with LeRobot's robot_client process is tests/deploy/test_async_inference.py.
"""

import json
import pickle
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.utils.constants import OBS_ENV_STATE, OBS_STATE

from tests.deploy.helpers import (
    ACTION_NAMES,
    ENV_NAMES,
    JOINTS,
    STATE_NAMES,
    TCP,
    dataset_features,
    random_checkpoint,
    raw_observation,
    robot_features,
)

grpc = pytest.importorskip("grpc", reason="the async extra: pip install -e '.[async]'")

@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return random_checkpoint(tmp_path_factory.mktemp("ckpt") / "pretrained_model")


@pytest.fixture
def server(tmp_path, monkeypatch):
    """The server on a free loopback port; LeRobot's stub connected to it. LeRobot's server module writes
    logs/ into the working directory when imported: keep that in tmp_path."""
    monkeypatch.chdir(tmp_path)
    torch.set_num_threads(1)
    from lerobot.transport import services_pb2_grpc

    from lerobot_focal.deploy.policy_server import start_server

    grpc_server, servicer, port = start_server(_config())
    channel = grpc.insecure_channel(f"127.0.0.1:{port}")
    stub = services_pb2_grpc.AsyncInferenceStub(channel)
    yield stub, servicer
    channel.close()
    grpc_server.stop(grace=0)


def _config():
    from lerobot_focal.deploy.policy_server import FocalPolicyServerConfig

    cfg = FocalPolicyServerConfig(host="127.0.0.1", fps=30, inference_latency=0.0, obs_queue_timeout=2)
    cfg.port = 0  # after validation: let the OS pick a free port
    return cfg


def _connect(stub, checkpoint: Path, policy_type: str = "focal"):
    from lerobot.async_inference.helpers import RemotePolicyConfig
    from lerobot.transport import services_pb2

    stub.Ready(services_pb2.Empty())
    specs = RemotePolicyConfig(policy_type, str(checkpoint), robot_features(), 4, "cpu")
    stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))


def _send(stub, timestep: int, raw: dict, must_go: bool) -> None:
    from lerobot.async_inference.helpers import TimedObservation
    from lerobot.transport import services_pb2
    from lerobot.transport.utils import send_bytes_in_chunks

    obs = TimedObservation(timestamp=0.0, timestep=timestep, observation=raw, must_go=must_go)
    stub.SendObservations(send_bytes_in_chunks(pickle.dumps(obs), services_pb2.Observation))


def _get(stub) -> list:
    from lerobot.transport import services_pb2

    reply = stub.GetActions(services_pb2.Empty())
    assert len(reply.data) > 0, "empty answer"
    return pickle.loads(reply.data)


def _sync_chunks(checkpoint: Path, frames: list[dict], seed: int | None = None) -> list[np.ndarray]:
    """What `lerobot-rollout` computes: LeRobot's SyncInferenceEngine, one call per control step, on the frames
    LeRobot's build_dataset_frame makes from the same raw observations. Returns the 4 actions after each frame
    at which a chunk is computed (the first frame and every 4th after it)."""
    from lerobot.policies import get_policy_class, make_pre_post_processors
    from lerobot.rollout.inference.sync import SyncInferenceEngine
    from lerobot.utils.feature_utils import build_dataset_frame

    policy_type = json.loads((checkpoint / "config.json").read_text())["type"]
    policy = get_policy_class(policy_type).from_pretrained(checkpoint)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    features = dataset_features()
    engine = SyncInferenceEngine(policy, pre, post, features, ACTION_NAMES, "move the arm", "cpu", "ur10e")
    engine.reset()
    actions = []
    for i, raw in enumerate(frames):
        if seed is not None and i % 4 == 0:
            torch.manual_seed(seed + i // 4)  # the noise of a diffusion chunk
        actions.append(engine.get_action(build_dataset_frame(features, raw, prefix="observation")).numpy())
    return [np.stack(actions[i:i + 4]) for i in range(0, len(actions), 4)]


def test_state_and_environment_state_come_from_the_training_datasets_names():
    from lerobot_focal.deploy.observation import InputNeeds, plan_observation

    needs = InputNeeds(keys=(OBS_STATE, OBS_ENV_STATE, "observation.images.front"),
                       shapes={OBS_STATE: (7,), OBS_ENV_STATE: (3,), "observation.images.front": (3, 12, 16)})
    plan = plan_observation(needs, robot_features(), dataset_features())
    raw = raw_observation(3)
    frame = plan.frame(raw)
    np.testing.assert_array_equal(frame[OBS_STATE], np.float32([raw[k] for k in STATE_NAMES]))
    np.testing.assert_array_equal(frame[OBS_ENV_STATE], np.float32([raw[k] for k in ENV_NAMES]))
    assert frame["observation.images.front"] is raw["front"]
    # RGB at another size than trained is resized (as LeRobot's server does); the tensors are rollout's.
    batch = plan.to_policy_input(frame, "cpu", "t")
    assert batch["observation.images.front"].shape == (1, 3, 12, 16) and batch[OBS_STATE].shape == (1, 7)
    # Without the dataset, observation.state is the robot's 13 floats, as LeRobot records them.
    plan = plan_observation(InputNeeds(keys=(OBS_STATE,), shapes={OBS_STATE: (13,)}), robot_features())
    assert plan.vectors[OBS_STATE] == (*JOINTS, *TCP, "gripper.pos")


def test_what_the_robot_lacks_is_listed_with_the_fix():
    from lerobot_focal.deploy.observation import InputNeeds, ObservationMismatchError, plan_observation

    needs = InputNeeds(
        keys=(OBS_STATE, OBS_ENV_STATE, "observation.images.wrist", "observation.images.front_depth"),
        shapes={OBS_STATE: (9,)}, depth_sizes={"observation.images.front_depth": (48, 64)},
    )
    features = {**dataset_features(), OBS_ENV_STATE: {"dtype": "float32", "shape": [2], "names": ["cube_x", "cube_y"]}}
    with pytest.raises(ObservationMismatchError) as err:
        plan_observation(needs, robot_features(), features)
    text = str(err.value)
    assert "'observation.state': the checkpoint reads 9 values" in text
    assert "the robot sends no ['cube_x', 'cube_y']" in text
    assert "no camera 'wrist'" in text
    assert "48x64 depth camera, the robot's 'front_depth' is 24x32" in text
    assert "cameras ['front', 'front_depth']" in text
    with pytest.raises(ObservationMismatchError, match="--dataset_root"):
        plan_observation(InputNeeds(keys=(OBS_ENV_STATE,), shapes={}), robot_features())


def test_chunks_use_both_frames_and_match_the_synchronous_rollout(server, checkpoint):
    stub, servicer = server
    _connect(stub, checkpoint)
    assert servicer.stacks_history and servicer.n_obs_steps == 2
    raws = [raw_observation(i) for i in range(5)]
    # Session start: frame 0 (nothing executed yet) -> actions 0..3, all of which the client executes.
    _send(stub, 0, raws[0], must_go=True)
    first = _get(stub)
    assert [a.get_timestep() for a in first] == [0, 1, 2, 3]
    # The client streams: after executing action 2 (queue at 1), then after action 3 (queue empty, must go).
    # LeRobot's filter drops the first ("too similar"); the server still keeps it as frame 3 of the history.
    _send(stub, 2, raws[3], must_go=False)
    _send(stub, 3, raws[4], must_go=True)
    second = _get(stub)
    # The chunk computed after 4 executed actions starts with action 4 (LeRobot stamps it 3, already done).
    assert [a.get_timestep() for a in second] == [4, 5, 6, 7]

    # lerobot-rollout on frames 0..4: chunk 1 from (0, 0), chunk 2 from (3, 4).
    sync = _sync_chunks(checkpoint, raws[:4] + [raws[4]] * 4)
    got = [np.stack([a.get_action().numpy() for a in chunk]) for chunk in (first, second)]
    np.testing.assert_allclose(got[0], sync[0], atol=1e-5)
    np.testing.assert_allclose(got[1], sync[1], atol=1e-5)
    # ... which is not what a copied frame gives (LeRobot's server: one frame, repeated).
    copied = _sync_chunks(checkpoint, [raws[4]] * 4)[0]
    assert np.abs(got[1] - copied).max() > 1e-3


def test_the_start_observation_streamed_during_the_first_chunk_gets_no_second_chunk(server, checkpoint):
    """LeRobot's filters start once a chunk is done; until then its client streams its start observation, and a
    second chunk for it would make the client execute action 0 twice (tests/deploy/test_async_inference.py)."""
    import threading

    stub, servicer = server
    _connect(stub, checkpoint)
    computing, release = threading.Event(), threading.Event()
    predict = servicer._predict_action_chunk

    def slow_first_chunk(obs):
        computing.set()
        assert release.wait(30)
        return predict(obs)

    servicer._predict_action_chunk = slow_first_chunk
    _send(stub, 0, raw_observation(0), must_go=True)
    first: list = []
    getter = threading.Thread(target=lambda: first.append(_get(stub)))
    getter.start()
    assert computing.wait(30)
    _send(stub, 0, raw_observation(0), must_go=False)  # the client's stream while it waits (must_go cleared)
    assert servicer.observation_queue.empty()
    release.set()
    getter.join(30)
    assert [a.get_timestep() for a in first[0]] == [0, 1, 2, 3]
    _send(stub, 0, raw_observation(1), must_go=True)  # must_go still goes through
    assert not servicer.observation_queue.empty()


def test_a_new_client_starts_a_new_history(server, checkpoint):
    stub, _ = server
    _connect(stub, checkpoint)
    _send(stub, 0, raw_observation(0), must_go=True)
    _get(stub)
    _send(stub, 0, raw_observation(1), must_go=True)
    _get(stub)
    _connect(stub, checkpoint)  # Ready again: frame 0 of a new session, no frame of the old one
    _send(stub, 0, raw_observation(7), must_go=True)
    chunk = _get(stub)
    assert [a.get_timestep() for a in chunk] == [0, 1, 2, 3]
    np.testing.assert_allclose(np.stack([a.get_action().numpy() for a in chunk]),
                               _sync_chunks(checkpoint, [raw_observation(7)] * 4)[0], atol=1e-5)


def test_a_robot_without_an_input_is_refused_at_set_up(server, tmp_path):
    stub, _ = server
    cube = ["cube_x.pos", "cube_y.pos", "cube_z.pos"]
    ckpt = random_checkpoint(tmp_path / "needs_cube" / "pretrained_model", env_names=cube)
    with pytest.raises(grpc.RpcError) as err:
        _connect(stub, ckpt)
    assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert f"'observation.environment_state': the robot sends no {cube}" in err.value.details()
    with pytest.raises(grpc.RpcError, match="Policy type 'nope' is not served"):
        _connect(stub, ckpt, policy_type="nope")


def test_a_failing_observation_reaches_the_client_and_the_next_one_is_served(server, checkpoint):
    stub, _ = server
    _connect(stub, checkpoint)
    bad = raw_observation(0)
    bad["elbow.pos"] = float("nan")
    _send(stub, 0, bad, must_go=True)
    with pytest.raises(grpc.RpcError) as err:
        _get(stub)
    assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "the policy failed on observation #0" in err.value.details()
    assert re.search(r"'observation.state' contains \d+ NaN/inf value", err.value.details())
    # The client clears must_go after sending; the server still takes the next observation.
    del bad["elbow.pos"]
    _send(stub, 0, bad, must_go=False)
    with pytest.raises(grpc.RpcError, match=r"lacks \['elbow.pos'\]"):
        _get(stub)
    _send(stub, 0, raw_observation(0), must_go=False)
    assert len(_get(stub)) == 4


def test_diffusion_fco_is_served_with_its_two_frames(server, tmp_path):
    """LeRobot's diffusion family (here the plugin's diffusion_fco, 2 observation frames) gets its window too:
    the chunk equals the synchronous engine's with the same noise."""
    stub, servicer = server
    ckpt = random_checkpoint(tmp_path / "dp" / "pretrained_model", policy_type="diffusion_fco")
    _connect(stub, ckpt, policy_type="diffusion_fco")
    assert servicer.stacks_history and servicer.n_obs_steps == 2
    raws = [raw_observation(i) for i in range(5)]
    torch.manual_seed(10)
    _send(stub, 0, raws[0], must_go=True)
    first = _get(stub)
    _send(stub, 2, raws[3], must_go=False)
    _send(stub, 3, raws[4], must_go=True)
    torch.manual_seed(11)
    second = _get(stub)
    sync = _sync_chunks(ckpt, raws[:4] + [raws[4]] * 4, seed=10)
    got = [np.stack([a.get_action().numpy() for a in chunk]) for chunk in (first, second)]
    for chunk, want in zip(got, sync, strict=True):
        np.testing.assert_allclose(chunk, want, atol=1e-5)
    assert np.abs(got[1] - _sync_chunks(ckpt, [raws[4]] * 4, seed=11)[0]).max() > 1e-3  # not one frame copied
