"""The paper's metrics, as pure functions of recorded numbers (tested on their own in tests/benchmarks).

* top-k score: mean of the k best evaluations of a run (paper: k = 5), then mean ± std over seeds;
* evaluation curve: LeRobot's evaluation episodes grouped back into evaluations (see ``eval_curve``);
* ATV: ``lerobot_focal.envs.episode_metrics.action_total_variation``, recorded by the env for every executed episode;
* TS score: |TS(expert) − TS(policy)| on the same held-out episodes. The paper takes TS from CoLA, whose exact
  formula is not in our references; we use the mean second difference ‖a_{t+1} − 2a_t + a_{t−1}‖₂ of the
  action sequence (a smoothness measure of the same kind) and say so in every report;
* open-loop compounding error (paper appendix): start positions at the origin, integrate the incremental xyz
  actions of the policy and of the expert along a held-out episode, and take their Euclidean distance at each
  step. The policy sees the held-out episode's recorded observations, never the consequences of its own actions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def top_k_mean(values: Sequence[float], k: int) -> float:
    if not values:
        return math.nan
    return float(np.mean(sorted(values, reverse=True)[:k]))


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and population std (the paper's ± over seeds); NaN for no values."""
    v = np.asarray([x for x in values if x is not None and not math.isnan(x)], dtype=np.float64)
    if v.size == 0:
        return math.nan, math.nan
    return float(v.mean()), float(v.std())


def eval_curve(episodes: list[dict], episodes_per_eval: int, eval_every: int) -> list[dict]:
    """Group the env's per-episode records into LeRobot's periodic evaluations.

    `lerobot-train` evaluates ``episodes_per_eval`` episodes every ``eval_every`` steps, with one vector env
    per episode reset with a seed; episodes an env starts by itself after finishing (autoreset) carry no seed
    and are not part of the evaluation, so they are dropped here. Records are in order, one block per evaluation.
    """
    seeded = [e for e in episodes if e.get("seed") is not None]
    if len(seeded) % episodes_per_eval:
        raise ValueError(
            f"{len(seeded)} seeded evaluation episodes is not a multiple of {episodes_per_eval} per evaluation; "
            "was the run interrupted during an evaluation, or eval.batch_size != eval.n_episodes?"
        )
    curve = []
    for i in range(len(seeded) // episodes_per_eval):
        block = seeded[i * episodes_per_eval : (i + 1) * episodes_per_eval]
        curve.append(
            {
                "step": (i + 1) * eval_every,
                "success": float(np.mean([e["success"] for e in block])),
                "atv": float(np.mean([e["action_total_variation"] for e in block])),
                "length": float(np.mean([e["length"] for e in block])),
            }
        )
    return curve


def trajectory_smoothness(actions: np.ndarray) -> float:
    """Mean ‖a_{t+1} − 2a_t + a_{t−1}‖₂ over a (T, d) action sequence (0 for T < 3)."""
    a = np.asarray(actions, dtype=np.float64)
    if a.shape[0] < 3:
        return 0.0
    return float(np.linalg.norm(np.diff(a, n=2, axis=0), axis=1).mean())


def ts_score(expert: Sequence[np.ndarray], policy: Sequence[np.ndarray]) -> float:
    """|TS_expert − TS_policy| with each TS averaged over the same episodes."""
    ts_e = np.mean([trajectory_smoothness(a) for a in expert])
    ts_p = np.mean([trajectory_smoothness(a) for a in policy])
    return float(abs(ts_e - ts_p))


def compounding_error(expert: np.ndarray, policy: np.ndarray, position_dims: int = 3) -> np.ndarray:
    """Per-step Euclidean distance between the integrated incremental positions of two (T, d) action sequences."""
    e = np.cumsum(np.asarray(expert, dtype=np.float64)[:, :position_dims], axis=0)
    p = np.cumsum(np.asarray(policy, dtype=np.float64)[:, :position_dims], axis=0)
    if e.shape != p.shape:
        raise ValueError(f"expert {e.shape} and policy {p.shape} action sequences differ in shape")
    return np.linalg.norm(e - p, axis=1)


def paired_difference(a: Sequence[float], b: Sequence[float], confidence: float = 0.95) -> dict:
    """Mean of the paired differences a_i − b_i with a Student-t confidence interval, and wins/ties/losses.

    Pairs share task and seed (same demos, same evaluation episodes), so the task-to-task spread that dominates
    a difference of two means cancels. With one pair the interval is unbounded (NaN).
    """
    from scipy import stats

    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    n = int(d.size)
    out = {"n": n, "mean": math.nan, "lo": math.nan, "hi": math.nan,
           "wins": int((d > 0).sum()), "ties": int((d == 0).sum()), "losses": int((d < 0).sum())}
    if n == 0:
        return out
    out["mean"] = float(d.mean())
    if n > 1:
        half = float(stats.t.ppf(0.5 + confidence / 2, n - 1) * d.std(ddof=1) / math.sqrt(n))
        out["lo"], out["hi"] = out["mean"] - half, out["mean"] + half
    return out


def mean_curve(curves: Sequence[np.ndarray]) -> np.ndarray:
    """Element-wise mean of curves cut to the shortest one."""
    n = min(len(c) for c in curves)
    return np.mean([np.asarray(c[:n]) for c in curves], axis=0)
