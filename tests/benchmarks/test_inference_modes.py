"""`lerobot-focal-bench inference-modes`: the simulated delayed execution, its metrics and its report."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from lerobot_focal.benchmarks.inference_modes import (
    READING_MARKER,
    chunk_variation,
    run_episode,
    summarise,
    write_report,
)

S, L = 4, 12  # executed actions per chunk (H), macro-trajectory length


class _Policy:
    """Chunk k holds 100·k + i at index i, so an executed action tells which chunk and index it was."""

    def __init__(self):
        self.config = SimpleNamespace(n_action_steps=S, n_obs_steps=2, used_observation_keys=["observation.state"])
        self.calls: list[dict] = []

    def reset(self):
        self.calls.clear()

    def predict_action_chunk(self, batch, inference_delay, prev_chunk_left_over):
        k = len(self.calls)
        self.calls.append({"obs": batch["observation.state"].clone(), "delay": inference_delay,
                           "prev": None if prev_chunk_left_over is None else prev_chunk_left_over.clone()})
        return (100.0 * k + torch.arange(L, dtype=torch.float32)).view(1, L, 1)


class _Env:
    def __init__(self):
        self.t, self.sent = 0, None

    def reset(self, seed):
        self.t = 0
        return {"observation.state": torch.tensor([[0.0]])}

    def step(self, action):
        self.sent = action[0].numpy().copy()
        self.t += 1
        return {"observation.state": torch.tensor([[float(self.t)]])}, False

    def success(self):
        return True


@pytest.mark.parametrize("delay", [0, 1, 3])
@pytest.mark.parametrize("guided", [False, True])
def test_chunks_switch_delay_steps_after_their_observation(delay, guided):
    policy = _Policy()
    ep = run_episode(_Env(), policy, lambda o: o, lambda a: a, seed=0, delay=delay, guided=guided, max_steps=20)
    executed = ep.actions[:, 0]
    # The first chunk is waited for and runs until the second arrives (S + delay actions); chunk k then runs
    # from its index `delay` for S actions.
    expected = list(range(S + delay))
    for k in range(1, 6):
        expected += [100 * k + delay + i for i in range(S)]
    np.testing.assert_array_equal(executed, expected[:20])
    later_chunks = [k for k in range(1, 6) for _ in range(S)][: 20 - S - delay]
    np.testing.assert_array_equal(ep.chunk_ids, [0] * (S + delay) + later_chunks)
    assert len(ep.latencies_s) == 5 and ep.success
    for k, call in enumerate(policy.calls):
        # Observations t-1, t at the chunk's step t = k·S (the first one twice).
        assert call["obs"].flatten().tolist() == ([0.0, 0.0] if k == 0 else [k * S - 1.0, k * S])
        assert call["delay"] == delay
        if k == 0 or not guided:
            assert call["prev"] is None
        else:  # the previous chunk's actions from this step on: its index S onwards
            assert call["prev"].flatten().tolist() == [100.0 * (k - 1) + i for i in range(S, L)]


def test_a_delay_of_a_whole_chunk_is_refused():
    with pytest.raises(ValueError, match="delay must be in"):
        run_episode(_Env(), _Policy(), lambda o: o, lambda a: a, seed=0, delay=S, guided=True, max_steps=5)


def test_variation_inside_chunks_and_at_switches():
    actions = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [5.0, 7.0], [6.0, 8.0]])
    ids = np.array([0, 0, 0, 1, 1])
    v = chunk_variation(actions, ids)
    assert v["in_chunk"] == pytest.approx(1.0)
    assert v["boundary"] == pytest.approx(4.0)  # mean of |5-2| and |7-2|
    assert v["atv"] == pytest.approx((1 + 1 + 4 + 1) / 4)


def test_report_files_and_the_hand_written_reading_survive_regeneration(tmp_path):
    ep = run_episode(_Env(), _Policy(), lambda o: o, lambda a: a, seed=0, delay=1, guided=True, max_steps=12)
    cell = summarise([ep, ep])
    result = {"command": "lerobot-focal-bench inference-modes --envs metaworld", "machine": "test", "wall_min": 1.0,
              "environments": {"metaworld": {"title": "MetaWorld x", "scale": "2 episodes",
                                             "results": {"focal": {"0": cell}, "focal_rtc": {"0": cell}}}}}
    write_report(result, tmp_path)
    md = tmp_path / "inference_modes.md"
    assert "| focal + RTC | 0 | 2/2 |" in md.read_text()
    md.write_text(md.read_text() + "RTC halves the jump.\n")
    write_report(result, tmp_path)
    text = md.read_text()
    assert text.count(READING_MARKER) == 1 and text.endswith("RTC halves the jump.\n")
    assert json.loads((tmp_path / "inference_modes.json").read_text())["environments"]["metaworld"]["title"]
    assert (tmp_path / "inference_modes.png").stat().st_size > 1000
