"""eval-profile's grouping: who a function's own time is charged to."""

from lerobot_focal.benchmarks.eval_profile import _which

PC = "point clouds (ray casting, crop, farthest-point sampling)"
SIM = "simulator (MuJoCo, MetaWorld, gymnasium MuJoCo)"


def test_ray_casting_and_env_wrappers_named_after_metaworld_are_not_charged_to_the_simulator():
    assert _which("~", "<built-in method mujoco._functions.mj_multiRay>") == PC
    assert _which("~", "<built-in method mujoco._functions.mj_ray>") == PC
    assert _which("/venv/lerobot_focal/geometry/pointcloud.py", "_exact_fps") == PC
    assert _which("~", "<built-in method mujoco._functions.mj_step>") == SIM
    assert _which("/venv/site-packages/metaworld/envs/sawyer_push_wall_v3.py", "evaluate_state") == SIM
    assert _which("/venv/lerobot_focal/envs/metaworld_env.py", "step") == "focal env wrapper and metrics"
    assert _which("/venv/site-packages/lerobot/envs/metaworld.py", "reset") == "vector env + LeRobot env wrappers"
