"""Where the seconds of one `lerobot-eval` go, grouped by who spends them.

    lerobot-focal-bench eval-profile --checkpoint <pretrained_model> --task pick-place [--episodes 20]
    lerobot-focal-bench eval-profile --checkpoint <point-cloud checkpoint> --obs-type pointcloud --task push-wall

Runs LeRobot's own `lerobot-eval` (focal_metaworld, the grid's settings; state + object poses, or 512-point
clouds) under cProfile in a subprocess and sums each function's own time (tottime) into groups by the file it
lives in: the simulator (MuJoCo, MetaWorld, gymnasium's MuJoCo env), the point clouds (ray casting, crop,
farthest-point sampling), LeRobot's rollout loop and processors, the policy (the plugin's policy code and
torch), video encoding (PyAV), imports and start-up, and the rest. cProfile adds overhead per Python call, so
the groups are shares, not timings; the run's own `eval_s` (LeRobot's timer, without the profiler) is reported
beside them. Writes ``eval_profile.json`` and ``eval_profile.md`` (``eval_profile_pointcloud.*`` for clouds).
"""

from __future__ import annotations

import json
import os
import pstats
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from lerobot_focal.console import console_script, doc_parser

GROUPS: list[tuple[str, re.Pattern]] = [
    # Before the simulator: MuJoCo's ray casting is a MuJoCo built-in, but it is the point clouds' cost.
    ("point clouds (ray casting, crop, farthest-point sampling)",
     re.compile(r"lerobot_focal/(sim|geometry)/|mj_multiRay|mj_ray\b")),
    # Before the simulator too: our env modules and LeRobot's are named after MetaWorld (metaworld_env.py).
    ("focal env wrapper and metrics", re.compile(r"lerobot_focal/envs")),
    ("vector env + LeRobot env wrappers", re.compile(r"gymnasium/vector|gymnasium/core|lerobot/envs")),
    ("simulator (MuJoCo, MetaWorld, gymnasium MuJoCo)", re.compile(r"mujoco|metaworld|gymnasium/envs")),
    ("policy (plugin policy code, torch)",
     re.compile(r"lerobot_focal/policy|torch/|<built-in method torch|<method '.*' of 'torch")),
    ("LeRobot processors", re.compile(r"lerobot/processor")),
    ("LeRobot rollout loop", re.compile(r"lerobot/scripts/lerobot_eval")),
    ("video encoding (PyAV)", re.compile(r"av/|'av\.")),
    ("imports and start-up", re.compile(r"importlib|<frozen|draccus|site-packages/.*/__init__\.py")),
    ("numpy / scipy Python code (observations, metrics)", re.compile(r"site-packages/(numpy|scipy)/")),
    ("Python standard library (mostly start-up: dataclasses, inspect, json)",
     re.compile(r"lib/python3\.\d+/(?!site-packages)")),
]


def _which(file: str, func: str) -> str:
    where = f"{file}:{func}"
    for name, pattern in GROUPS:
        if pattern.search(where):
            return name
    return "other"


def _group(stats: pstats.Stats) -> dict[str, float]:
    """Own time per group. A C built-in (numpy, MuJoCo bindings, ...) has no file of its own: its time goes to
    the groups of its callers, split by the time spent under each caller."""
    out: dict[str, float] = {name: 0.0 for name, _ in GROUPS}
    out["other"] = 0.0
    for (file, _line, func), (_cc, _nc, tottime, _ct, callers) in stats.stats.items():
        group = _which(file, func)
        if file == "~" and group == "other" and callers:
            edge_total = sum(edge[2] for edge in callers.values()) or 1.0
            for (cfile, _cline, cfunc), edge in callers.items():
                out[_which(cfile, cfunc)] += tottime * edge[2] / edge_total
            continue
        out[group] += tottime
    return out


def run(checkpoint: Path, task: str, episodes: int, out: Path, obs_type: str = "state") -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        prof = Path(tmp) / "eval.prof"
        cmd = [sys.executable, "-m", "cProfile", "-o", str(prof), console_script("lerobot-eval"),
               f"--policy.path={checkpoint}", "--env.type=focal_metaworld", f"--env.task={task}",
               f"--env.obs_type={obs_type}", f"--env.env_state={str(obs_type == 'state').lower()}",
               "--env.render_videos=false",
               "--env.observation_width=64", "--env.observation_height=64", f"--eval.n_episodes={episodes}",
               f"--eval.batch_size={episodes}", "--eval.use_async_envs=false", "--seed=300000",
               f"--output_dir={Path(tmp) / 'eval'}"]
        env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=1800)
        if proc.returncode != 0:
            raise SystemExit(f"lerobot-eval failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
        info = json.loads((Path(tmp) / "eval" / "eval_info.json").read_text())
        stats = pstats.Stats(str(prof))
    groups = _group(stats)
    total = sum(groups.values())
    result = {"checkpoint": str(checkpoint), "task": task, "obs_type": obs_type, "episodes": episodes,
              "eval_s": info["overall"].get("eval_s"), "pc_success": info["overall"].get("pc_success"),
              "profiled_total_s": total, "groups_s": groups,
              "groups_share": {k: v / total for k, v in groups.items()}}
    out.mkdir(parents=True, exist_ok=True)
    stem = "eval_profile" if obs_type == "state" else f"eval_profile_{obs_type}"
    flag = "" if obs_type == "state" else f" --obs-type {obs_type}"
    (out / f"{stem}.json").write_text(json.dumps(result, indent=1))
    md = [f"# Where one evaluation's time goes: {episodes} episodes of {task} ({obs_type}), one process", "",
          f"`lerobot-focal-bench eval-profile --checkpoint <focal checkpoint>{flag} --task {task} "
          f"--episodes {episodes}`: "
          "LeRobot's `lerobot-eval` under cProfile, own time of every function summed by where it lives, C "
          "built-ins charged to their callers (shares; the profiler slows Python calls). LeRobot's own timer for the "
          f"rollouts in the same, profiled, process: eval_s = {result['eval_s']:.1f} s; success "
          f"{result['pc_success']:.0f} %.", "",
          "| group | seconds (profiled) | share |", "|---|---|---|"]
    md += [f"| {k} | {v:.2f} | {v / total * 100:.0f} % |" for k, v in sorted(groups.items(), key=lambda kv: -kv[1])]
    (out / f"{stem}.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return result


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench eval-profile")
    p.add_argument("--checkpoint", type=Path, required=True,
                   help="a focal pretrained_model directory trained on the observations --obs-type names")
    p.add_argument("--obs-type", choices=["state", "pointcloud"], default="state",
                   help="state: 9-d state + MetaWorld's object poses (the grid's low-dim runs); pointcloud: "
                        "9-d state + 512-point cloud (focal_pc)")
    p.add_argument("--task", default="pick-place")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    args = p.parse_args(argv)
    run(args.checkpoint, args.task, args.episodes, args.out, args.obs_type)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
