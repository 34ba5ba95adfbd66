"""The execution-cost diagnostic: its chunked expert replays exactly, its variants act differently, and the
command writes its table, JSON and plot."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lerobot_focal.benchmarks.execution_cost import (
    EXECUTION_COST_SEED,
    Variant,
    _make_env,
    main,
    run_episode,
)


@pytest.fixture(scope="module")
def envs():
    env, shadow = _make_env("reach", 40), _make_env("reach", 44)
    yield env, shadow
    env.close()
    shadow.close()


def _actions(envs, variant: Variant) -> np.ndarray:
    _, _, actions = run_episode(*envs, EXECUTION_COST_SEED, variant, 40, np.random.default_rng(0))
    return np.stack(actions)


def test_chunks_of_the_experts_own_next_actions_equal_closed_loop_without_noise(envs):
    closed, chunked = _actions(envs, Variant("closed", 0.0)), _actions(envs, Variant("chunked", 0.0))
    np.testing.assert_array_equal(chunked, closed)  # the shadow replay reaches the executed state exactly
    hold = _actions(envs, Variant("hold", 0.0))
    assert all((hold[i] == hold[i - i % 4]).all() for i in range(len(hold)))  # one action per chunk
    assert not np.array_equal(hold, closed[: len(hold)])


def test_noise_is_added_to_every_executed_action_and_stays_in_range(envs):
    noisy = _actions(envs, Variant("chunked", 0.3))
    clean = _actions(envs, Variant("chunked", 0.0))
    assert np.abs(noisy).max() <= 1.0
    assert (noisy[0] != clean[0]).all()  # the same expert action at the same first state, perturbed in every dim


def test_command_writes_table_json_and_plot(tmp_path):
    assert main(["--tasks", "reach", "--episodes", "1", "--episode-length", "30", "--noise", "0.1",
                 "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "execution_cost.json").read_text())
    variants = [r["variant"] for r in result["results"]]
    assert variants == ["closed σ=0", "chunked σ=0", "hold σ=0", "closed σ=0.1", "chunked σ=0.1"]
    chunked0 = result["results"][1]
    assert chunked0["max_action_gap_to_closed"] == 0.0
    md = (tmp_path / "execution_cost.md").read_text()
    assert "| reach |" in md and "0 on every task" in md
    assert (tmp_path / "execution_cost.png").stat().st_size > 1000
