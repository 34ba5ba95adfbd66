"""How the focal envs are vectorised for `lerobot-eval` / `lerobot-train`'s evaluation.

Synchronous: gymnasium's ``SyncVectorEnv`` over envs wrapped in LeRobot's public ``freeze_after_episode_end``
(a finished sub-env stops simulating, and autoresetting, until the next rollout). Asynchronous: LeRobot's
``_LazyAsyncVectorEnv``, the one private LeRobot class the envs use. It is what LeRobot's own multi-task
benchmarks use: each task's worker processes start on its first reset, so evaluating a 50-task group keeps
n_envs processes alive instead of 50·n_envs. It is not re-implemented here so that LeRobot's fixes to it
(spaces, autoreset mode, forkserver) apply; `tests/envs/test_registration.py` fails loudly if its
constructor or laziness changes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym


def make_vector_env(env_fns: list[Callable[[], gym.Env]], use_async: bool, spaces: list | None = None) -> Any:
    """One task's vector env. ``spaces`` is a cache shared between a suite's tasks (async only): the first
    task's (observation_space, action_space, metadata), so later tasks do not build a throw-away env."""
    from lerobot.envs.utils import freeze_after_episode_end

    if use_async and len(env_fns) > 1:
        from lerobot.envs.utils import _LazyAsyncVectorEnv  # see the module docstring

        cached = spaces[0] if spaces else (None, None, None)
        env = _LazyAsyncVectorEnv(env_fns, *cached)
        if spaces is not None and not spaces:
            spaces.append((env.observation_space, env.action_space, env.metadata))
        return env
    return gym.vector.SyncVectorEnv([freeze_after_episode_end(fn) for fn in env_fns])
