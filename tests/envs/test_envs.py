"""Real MuJoCo sims: every env type x obs type resets and steps with the declared shapes; success is reported."""

import functools
import json

import numpy as np
import pytest

from lerobot_focal.config_errors import ConfigError
from lerobot_focal.envs.episode_metrics import action_total_variation
from lerobot_focal.envs.features import OBS_TYPES

pytest.importorskip("metaworld")

EXPECTED_KEYS = {
    "state": {"agent_pos"},
    "pointcloud": {"agent_pos", "pointcloud"},
    "pixels": {"pixels"},
    "pixels_agent_pos": {"pixels", "agent_pos"},
}


def _check_obs(env, obs, state_dim, image_hw):
    assert set(obs) == EXPECTED_KEYS[env.obs_type]
    assert env.observation_space.contains(obs)
    if "agent_pos" in obs:
        assert obs["agent_pos"].shape == (state_dim,) and obs["agent_pos"].dtype == np.float32
        assert np.all(np.isfinite(obs["agent_pos"]))
    if "pointcloud" in obs:
        cloud = obs["pointcloud"]
        assert cloud.shape == (512, 3) and cloud.dtype == np.float32
        assert len(np.unique(cloud, axis=0)) == 512  # a real FPS sample, not padding
        lo, hi = np.array(env.pointcloud_spec.bounds.low), np.array(env.pointcloud_spec.bounds.high)
        assert np.all(cloud > lo) and np.all(cloud < hi)
    if "pixels" in obs:
        img = obs["pixels"]
        assert img.shape == (*image_hw, 3) and img.dtype == np.uint8
        assert img.std() > 5  # a rendered scene, not a blank frame


@pytest.mark.parametrize("obs_type", OBS_TYPES)
def test_metaworld_obs_types(obs_type):
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    env = FocalMetaworldEnvConfig(task="reach", obs_type=obs_type).make_single_env()
    try:
        obs, info = env.reset(seed=0)
        assert info["is_success"] is False
        _check_obs(env, obs, 9, (128, 128))
        first = obs
        for _ in range(3):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        _check_obs(env, obs, 9, (128, 128))
        assert isinstance(reward, float) and not terminated and not truncated and info["is_success"] is False
        if "agent_pos" in obs:
            # hand, right pad, left pad: pads straddle the hand, and the state moves with the arm
            hand, right, left = obs["agent_pos"].reshape(3, 3)
            assert np.linalg.norm(right - left) < 0.15 and np.linalg.norm((right + left) / 2 - hand) < 0.1
            assert not np.allclose(first["agent_pos"], obs["agent_pos"])
    finally:
        env.close()


def test_metaworld_env_state_is_metaworlds_own_observation():
    """env_state=true adds the 39-d observation the scripted experts read (object poses), declared as ENV."""
    from lerobot.configs import FeatureType

    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    cfg = FocalMetaworldEnvConfig(task="pick-place", obs_type="state", env_state=True, render_videos=False)
    assert cfg.features["environment_state"].type is FeatureType.ENV
    assert cfg.features_map["environment_state"] == "observation.environment_state"
    env = cfg.make_single_env()
    try:
        a, _ = env.reset(seed=1)
        assert a["environment_state"].shape == (39,) and a["environment_state"].dtype == np.float32
        np.testing.assert_allclose(a["environment_state"], env.last_raw_obs, rtol=1e-6)
        np.testing.assert_allclose(a["environment_state"][:3], a["agent_pos"][:3], atol=1e-5)  # hand position
        b, _ = env.reset(seed=2)
        assert not np.allclose(a["environment_state"][4:7], b["environment_state"][4:7])  # the object moved
        frame = env.render()
        assert frame.shape == (16, 16, 3) and not frame.any()  # render_videos=false: blank video frames
    finally:
        env.close()
    with pytest.raises(ConfigError, match="render_videos"):
        FocalMetaworldEnvConfig(task="reach", obs_type="pixels", render_videos=False)


def test_metaworld_seed_controls_object_positions():
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    env = FocalMetaworldEnvConfig(task="pick-place", obs_type="pointcloud").make_single_env()
    try:
        a, _ = env.reset(seed=1)
        b, _ = env.reset(seed=1)
        c, _ = env.reset(seed=2)
        np.testing.assert_array_equal(a["pointcloud"], b["pointcloud"])
        assert not np.array_equal(a["pointcloud"], c["pointcloud"])
    finally:
        env.close()


def test_metaworld_envs_share_one_task_per_process_and_observe_as_a_fresh_build(monkeypatch):
    """lerobot-train builds its evaluation envs anew at every evaluation: MetaWorld's MT1 (about a second,
    sampling 50 tasks) must run once per task and process, and a cached task must give the envs a fresh build gives."""
    import metaworld

    from lerobot_focal.envs import metaworld_env
    from lerobot_focal.envs.metaworld_env import FocalMetaworldEnv

    def first_obs(seed: int) -> dict:
        env = FocalMetaworldEnv(task="push-wall-v3", obs_type="state", env_state=True)
        try:
            return env.reset(seed=seed)[0]
        finally:
            env.close()

    uncached = metaworld_env.metaworld_task.__wrapped__
    monkeypatch.setattr(metaworld_env, "metaworld_task", uncached)
    fresh = [first_obs(s) for s in (0, 1)]
    builds = []
    real_mt1 = metaworld.MT1
    monkeypatch.setattr(metaworld, "MT1", lambda *a, **k: builds.append(a) or real_mt1(*a, **k))
    monkeypatch.setattr(metaworld_env, "metaworld_task", functools.cache(uncached))
    shared = [first_obs(s) for s in (0, 1, 0)]
    assert builds == [("push-wall-v3",)]
    for a, b in zip(fresh + fresh[:1], shared, strict=True):
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
    assert not np.array_equal(shared[0]["environment_state"], shared[1]["environment_state"])


@pytest.mark.parametrize("task, top", [("pick-place", 0.0), ("sweep-into", 0.05)])
def test_metaworld_cloud_crops_the_table_away_and_keeps_the_object(task, top):
    """The table top (5 cm higher in sweep-into) and its rim are cropped out of the cloud, as DP3 does: kept,
    farthest-point sampling spent most of the 512 points on them and left the object a handful."""
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig
    from lerobot_focal.envs.metaworld_env import table_top

    def cloud(**kwargs):
        env = FocalMetaworldEnvConfig(task=task, obs_type="pointcloud", **kwargs).make_single_env()
        try:
            obs, _ = env.reset(seed=3)
            obj = env.last_raw_obs[4:7]  # MetaWorld's own object position
            return obs["pointcloud"], np.linalg.norm(obs["pointcloud"] - obj, axis=1), table_top(
                env._env.model, env._env.data)
        finally:
            env.close()

    points, to_object, measured_top = cloud()
    assert measured_top == pytest.approx(top, abs=1e-6)
    assert points[:, 2].min() >= top + 0.005
    assert (to_object < 0.04).sum() >= 10
    # The old box (table and rim inside): the table plane holds a large share and the object only a few points.
    kept, kept_to_object, _ = cloud(table_clearance=None, workspace_low=(-0.6, 0.2, -0.02),
                                    workspace_high=(0.6, 1.05, 0.75))
    assert (np.abs(kept[:, 2] - top) < 0.003).sum() > 100
    assert (kept_to_object < 0.04).sum() < (to_object < 0.04).sum() / 2


@pytest.mark.parametrize("task", ["pick-place", "push-wall"])
def test_metaworld_cloud_shows_the_goal_marker_as_opengl_draws_it(task):
    """MetaWorld's goal is a drawn site, in DP3's rasterised clouds: ours hold it too (draw_sites, the default),
    or not, as a real depth camera would see the scene (draw_sites=false)."""
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    def near_goal(draw_sites):
        env = FocalMetaworldEnvConfig(task=task, obs_type="pointcloud", draw_sites=draw_sites).make_single_env()
        try:
            first, _ = env.reset(seed=3)  # the goal is drawn where it is from the first frame on
            counts = [int((np.linalg.norm(first["pointcloud"] - env.last_raw_obs[-3:], axis=1) < 0.03).sum())]
            obs, *_ = env.step(np.zeros(4, np.float32))
            counts.append(int((np.linalg.norm(obs["pointcloud"] - env.last_raw_obs[-3:], axis=1) < 0.03).sum()))
            return min(counts)
        finally:
            env.close()

    assert near_goal(True) >= 3
    assert near_goal(False) == 0


def test_metaworld_expert_success_terminates_with_metrics(tmp_path):
    """The scripted expert solves reach; the env reports success, terminates and logs ATV."""
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    metrics = tmp_path / "episodes.jsonl"
    env = FocalMetaworldEnvConfig(task="reach", obs_type="state", metrics_path=str(metrics)).make_single_env()
    try:
        env.reset(seed=0)
        actions = []
        for _ in range(env._max_episode_steps):
            action = env.expert_action()
            actions.append(action)
            _, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
        assert terminated and info["is_success"] and info["final_info"]["is_success"]
        assert info["action_total_variation"] == pytest.approx(action_total_variation(actions))
        record = json.loads(metrics.read_text().strip())
        assert record["success"] is True and record["length"] == len(actions) and record["seed"] == 0
    finally:
        env.close()


def test_metaworld_gripper_levels_snap_the_grip_command_and_refuse_nonsense():
    """With gripper_levels a grip command between the levels acts as the nearer level (the fingers end where the
    level's would, not where the raw command's would); without them the raw command acts."""
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    def fingers(command: float, **kwargs) -> np.ndarray:
        env = FocalMetaworldEnvConfig(task="pick-place", obs_type="state", **kwargs).make_single_env()
        try:
            env.reset(seed=0)
            for _ in range(15):
                obs, *_ = env.step(np.array([0.0, 0.0, 0.0, command], np.float32))
            return obs["agent_pos"]
        finally:
            env.close()

    snapped = fingers(0.7, gripper_levels=(0.0, 1.0))
    assert np.array_equal(snapped, fingers(1.0))  # 0.7 is nearer 1
    assert not np.allclose(snapped, fingers(0.7))  # the raw command closes the fingers less
    assert np.array_equal(fingers(0.3, gripper_levels=(0.0, 1.0)), fingers(0.0))
    for bad in ((1.0,), (0.5, 0.5), (0.0, float("nan"))):
        with pytest.raises(ConfigError, match="gripper_levels must be two different finite numbers"):
            FocalMetaworldEnvConfig(task="pick-place", obs_type="state", gripper_levels=bad)


def test_metaworld_truncates_at_episode_length():
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    env = FocalMetaworldEnvConfig(task="pick-place", obs_type="state", episode_length=12).make_single_env()
    try:
        env.reset(seed=0)
        flags = [env.step(np.zeros(4, np.float32))[2:4] for _ in range(12)]
        assert flags[-1] == (False, True) and all(f == (False, False) for f in flags[:-1])
    finally:
        env.close()


@pytest.mark.subprocess
def test_metaworld_vector_env_and_processor():
    """create_envs -> async vector env (lerobot-eval's default for batch_size > 1, simulators in worker
    processes); the env processor yields (B, 512, 3)."""
    import torch
    from lerobot.envs.utils import preprocess_observation

    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    cfg = FocalMetaworldEnvConfig(task="reach", obs_type="pointcloud")
    envs = cfg.create_envs(n_envs=2, use_async_envs=True)
    vec = envs["reach-v3"][0]
    try:
        obs, _ = vec.reset(seed=[0, 1])
        assert obs["pointcloud"].shape == (2, 512, 3) and obs["agent_pos"].shape == (2, 9)
        assert vec.call("_max_episode_steps")[0] == 200
        pre, _ = cfg.get_env_processors()
        batch = pre(preprocess_observation(obs))
        assert batch["observation.pointcloud"].shape == (2, 512, 3)
        assert batch["observation.pointcloud"].dtype == torch.float32
        assert batch["observation.state"].shape == (2, 9)
        with pytest.raises(KeyError, match="no point cloud"):
            pre({"observation.state": batch["observation.state"]})
    finally:
        vec.close()


@pytest.mark.parametrize(("suite", "task"), [("metaworld", "basketball"), ("metaworld", "disassemble"),
                                           ("adroit", "door"), ("adroit", "pen")])
def test_cloud_after_a_reset_that_moves_a_welded_body_is_the_cloud_of_a_fresh_env(suite, task):
    """Resets move bodies welded to the world (the hoop, the peg, the door frame, the target pen). The ray
    caster caches the depth of welded geoms; a reused env, as `lerobot-focal-collect` and `lerobot-eval` use
    them, once kept showing them where the first episode had put them."""
    from lerobot_focal.envs.focal_adroit import FocalAdroitEnvConfig
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    config = FocalMetaworldEnvConfig if suite == "metaworld" else FocalAdroitEnvConfig
    reused, fresh = (config(task=task, obs_type="pointcloud").make_single_env() for _ in range(2))
    try:
        first = reused.reset(seed=0)[0]["pointcloud"]
        again = reused.reset(seed=5)[0]["pointcloud"]
        np.testing.assert_array_equal(again, fresh.reset(seed=5)[0]["pointcloud"])
        assert not np.array_equal(first, again)
    finally:
        reused.close()
        fresh.close()


# Every obs type, every task, and a point cloud from every task (each case builds its own simulator).
ADROIT_CASES = [
    ("hammer", 26, "state"),
    ("hammer", 26, "pointcloud"),
    ("door", 28, "pointcloud"),
    ("door", 28, "pixels_agent_pos"),
    ("pen", 24, "pointcloud"),
    ("pen", 24, "pixels"),
]


@pytest.mark.parametrize("task,action_dim,obs_type", ADROIT_CASES)
def test_adroit_obs_types(task, action_dim, obs_type):
    pytest.importorskip("gymnasium_robotics")
    from lerobot_focal.envs.focal_adroit import FocalAdroitEnvConfig

    env = FocalAdroitEnvConfig(task=task, obs_type=obs_type).make_single_env()
    try:
        assert env.action_space.shape == (action_dim,)
        obs, info = env.reset(seed=0)
        assert info["is_success"] is False
        _check_obs(env, obs, 24, (84, 84))
        for _ in range(2):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        _check_obs(env, obs, 24, (84, 84))
        assert isinstance(reward, float) and "is_success" in info
    finally:
        env.close()


def test_adroit_door_success_reported():
    """Open the door in the simulator state: the env must report success and terminate."""
    pytest.importorskip("gymnasium_robotics")
    from lerobot_focal.envs.focal_adroit import FocalAdroitEnvConfig

    env = FocalAdroitEnvConfig(task="door", obs_type="state").make_single_env()
    try:
        env.reset(seed=0)
        _, _, terminated, _, info = env.step(np.zeros(28, np.float32))
        assert not terminated and info["is_success"] is False
        sim = env._env.unwrapped
        qpos, qvel = sim.data.qpos.copy(), sim.data.qvel.copy()
        qpos[sim.model.jnt_qposadr[sim.model.joint("door_hinge").id]] = 1.5  # rad, past the 1.35 success line
        sim.set_state(qpos, qvel)
        _, _, terminated, _, info = env.step(np.zeros(28, np.float32))
        assert terminated and info["is_success"] and info["final_info"]["is_success"]
    finally:
        env.close()


def test_action_total_variation():
    a = np.array([[0.0, 0.0], [1.0, -1.0], [1.0, 1.0]])
    # |1|+|-1| + |0|+|2| = 4 over (3-1)*2 = 4 entries
    assert action_total_variation(a) == pytest.approx(1.0)
    assert action_total_variation(a[:1]) == 0.0
