"""MetaWorld demo: scripted-expert demos -> `lerobot-train` (focal, CPU preset) -> `lerobot-eval`, on the CPU.

Three real processes, each showing its own progress:

1. ``python -m lerobot_focal.datasets.making.collect``: 10 full-length scripted-expert episodes of one MetaWorld v3
   task, written as a local LeRobotDataset (a rerun reuses what is already there);
2. ``lerobot-train --config_path=configs/focal_cpu_state.json`` (or ``focal_cpu.json`` for point clouds) with
   the plugin's in-memory reader (``LEROBOT_FOCAL_FAST_READER=1``);
3. ``lerobot-eval --env.type=focal_metaworld`` on fresh seeds (1000, 1001, ...), with per-episode success,
   length and Action Total Variation written by the env (``--env.metrics_path``).

It then prints the success rate beside the paper's FocalPolicy on the same task, and writes ``result.json``
and ``metaworld_demo.png`` (training loss parsed from the log, per-episode evaluation outcome) under ``--output``.

The default is button-press, whose inputs show the goal (the button's pose is in the object observation; reach's
goal is a site no observation shows, where the paper itself reaches 24 %), with low-dimensional inputs (9-d
state + 39-d object poses) and the small U-Net, trained near its plateau in a few minutes. ``--obs pointcloud``
trains on 512-point clouds with the CPU point-cloud preset instead (about 1 s per step on one core: 500 steps).

    python -m lerobot_focal.demos.metaworld                      # button-press, 3000 steps, 50 eval episodes
    python -m lerobot_focal.demos.metaworld --task drawer-open --output outputs/metaworld_drawer_open
    python -m lerobot_focal.demos.metaworld --obs pointcloud --steps 500
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

from lerobot_focal.benchmarks.paper_results import PAPER_FOCAL_METAWORLD
from lerobot_focal.console import console_script, doc_parser
from lerobot_focal.figures import save_png
from lerobot_focal.presets import preset_path

PRESETS = {"state": preset_path("cpu_state"), "pointcloud": preset_path("cpu")}
LOSS_RE = re.compile(r"step:(\S+) .*?\bloss:([0-9.eE+-]+)")


def _run(cmd: list[str], log_path: Path, env_extra: dict[str, str] | None = None) -> str:
    """Run `cmd`, streaming its output (progress bars included) to the terminal and to `log_path`."""
    env = {**os.environ, "WANDB_MODE": "disabled", **(env_extra or {})}
    prefix = " ".join(f"{k}={v}" for k, v in (env_extra or {}).items())
    print(f"\n[demo] $ {prefix + ' ' if prefix else ''}{' '.join(cmd)}", flush=True)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    chunks: list[bytes] = []
    with open(log_path, "wb") as log, subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env, cwd=os.getcwd()
    ) as proc:
        assert proc.stdout is not None
        while True:
            data = os.read(proc.stdout.fileno(), 65536)
            if not data:
                break
            chunks.append(data)
            log.write(data)
            sys.stdout.buffer.write(data)
            sys.stdout.flush()
        rc = proc.wait()
    if rc != 0:
        raise SystemExit(f"[demo] {Path(cmd[0]).name} failed with exit code {rc}; full log: {log_path}")
    return b"".join(chunks).decode(errors="replace")


def collect(task: str, episodes: int, root: Path, obs: str, log: Path) -> None:
    obs_types = "state,env_state" if obs == "state" else "pointcloud"
    _run([sys.executable, "-m", "lerobot_focal.datasets.making.collect", "--root", str(root), "--tasks", task,
          "--episodes", str(episodes), "--obs_types", obs_types], log)


def train(task: str, root: Path, out_dir: Path, obs: str, steps: int, batch_size: int, seed: int,
          log: Path) -> tuple[Path, str]:
    if out_dir.exists():
        shutil.rmtree(out_dir)  # lerobot-train refuses an existing output_dir unless resuming
    cmd = [
        console_script("lerobot-train"),
        f"--config_path={PRESETS[obs]}",
        f"--dataset.repo_id=local/metaworld_{task}",
        f"--dataset.root={root}",
        f"--output_dir={out_dir}",
        f"--steps={steps}",
        f"--batch_size={batch_size}",
        f"--save_freq={steps}",
        f"--log_freq={max(steps // 25, 1)}",
        f"--seed={seed}",
    ]
    # The plugin's in-memory reader (docs/data_throughput.md): the same items as LeRobot's reader, much cheaper.
    text = _run(cmd, log, {"LEROBOT_FOCAL_FAST_READER": "1"})
    return out_dir / "checkpoints" / "last" / "pretrained_model", text


def evaluate(task: str, checkpoint: Path, out_dir: Path, obs: str, n_episodes: int, batch_size: int,
             episode_length: int, log: Path) -> tuple[dict, list[dict]]:
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    metrics = out_dir / "episodes.jsonl"
    cmd = [
        console_script("lerobot-eval"),
        f"--policy.path={checkpoint}",
        "--env.type=focal_metaworld",
        f"--env.task={task}",
        f"--env.obs_type={obs}",
        f"--env.env_state={str(obs == 'state').lower()}",
        f"--env.episode_length={episode_length}",
        "--env.render_videos=false",
        f"--env.metrics_path={metrics}",
        f"--eval.n_episodes={n_episodes}",
        f"--eval.batch_size={min(batch_size, n_episodes)}",
        "--eval.use_async_envs=false",
        "--policy.device=cpu",
        f"--output_dir={out_dir}",
    ]
    _run(cmd, log)
    info = json.loads((out_dir / "eval_info.json").read_text())
    episodes = [json.loads(line) for line in metrics.read_text().splitlines() if line.strip()]
    return info, episodes


def parse_losses(train_log: str, log_freq: int) -> tuple[list[int], list[float]]:
    """(step, loss) of every `lerobot-train` log line; steps counted from log_freq (the log rounds them: 1K)."""
    losses = [float(m.group(2)) for m in LOSS_RE.finditer(train_log)]
    return [log_freq * (i + 1) for i in range(len(losses))], losses


def plot(steps: list[int], losses: list[float], episodes: list[dict], title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 4))
    ax0.plot(steps, losses, marker=".", color="C0")
    ax0.set_yscale("log")
    ax0.set_xlabel("training step")
    ax0.set_ylabel("loss (lerobot-train log)")
    ax0.set_title("focal training loss")
    ax0.grid(alpha=0.3)

    episodes = sorted(episodes, key=lambda e: (e["seed"] is None, e["seed"]))
    colors = ["C2" if e["success"] else "C3" for e in episodes]
    ax1.bar(range(len(episodes)), [e["length"] for e in episodes], color=colors)
    ax1.set_xticks(range(len(episodes)), [str(e["seed"]) for e in episodes], rotation=90, fontsize=7)
    ax1.set_xlabel("evaluation seed (green: success, red: failure)")
    ax1.set_ylabel("episode length (steps)")
    n_ok = sum(e["success"] for e in episodes)
    atv = sum(e["action_total_variation"] for e in episodes) / max(len(episodes), 1)
    ax1.set_title(f"lerobot-eval: {n_ok}/{len(episodes)} success, mean ATV {atv:.4f}")
    fig.suptitle(title)
    save_png(fig, path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "python -m lerobot_focal.demos.metaworld")
    parser.add_argument("--task", default="button-press", help="MetaWorld v3 task (default: button-press)")
    parser.add_argument("--obs", choices=sorted(PRESETS), default="state",
                        help="state: 9-d state + 39-d object poses (default); pointcloud: 512-point clouds + state")
    parser.add_argument("--episodes", type=int, default=10, help="expert demonstrations to collect (default 10)")
    parser.add_argument("--steps", type=int, default=None,
                        help="lerobot-train steps (default: 3000 with state, 500 with point clouds)")
    parser.add_argument("--batch-size", type=int, default=64, help="training batch size (default 64)")
    parser.add_argument("--eval-episodes", type=int, default=50, help="lerobot-eval episodes (default 50)")
    parser.add_argument("--eval-batch-size", type=int, default=25, help="parallel eval envs (default 25)")
    parser.add_argument("--eval-episode-length", type=int, default=200, help="env steps per eval episode (200)")
    parser.add_argument("--seed", type=int, default=1000, help="lerobot-train seed (default 1000)")
    parser.add_argument("--output", type=Path, default=Path("outputs/metaworld_demo"))
    args = parser.parse_args(argv)

    task = args.task.removeprefix("metaworld-").removesuffix("-v3")
    if args.steps is None:
        args.steps = 3000 if args.obs == "state" else 500
    out = args.output.resolve()
    out.mkdir(parents=True, exist_ok=True)
    data_root = out / "data" / f"{task}_{args.obs}"
    times: dict[str, float] = {}

    print(f"[demo] 1/3 collect {args.episodes} scripted-expert demos of {task}-v3 -> {data_root}", flush=True)
    t0 = time.perf_counter()
    collect(task, args.episodes, data_root, args.obs, out / "logs" / "collect.log")
    times["collect_s"] = time.perf_counter() - t0

    print(f"\n[demo] 2/3 train focal ({PRESETS[args.obs].name}) for {args.steps} steps, batch {args.batch_size}",
          flush=True)
    t0 = time.perf_counter()
    checkpoint, train_log = train(task, data_root, out / "train", args.obs, args.steps, args.batch_size, args.seed,
                                  out / "logs" / "train.log")
    times["train_s"] = time.perf_counter() - t0

    print(f"\n[demo] 3/3 evaluate {checkpoint} on {args.eval_episodes} episodes of {task}-v3", flush=True)
    t0 = time.perf_counter()
    info, episodes = evaluate(task, checkpoint, out / "eval", args.obs, args.eval_episodes, args.eval_batch_size,
                              args.eval_episode_length, out / "logs" / "eval.log")
    times["eval_s"] = time.perf_counter() - t0
    times["total_s"] = sum(times.values())

    steps, losses = parse_losses(train_log, max(args.steps // 25, 1))
    success = float(info["overall"]["pc_success"])
    atv = sum(e["action_total_variation"] for e in episodes) / max(len(episodes), 1)
    png = out / "metaworld_demo.png"
    paper = PAPER_FOCAL_METAWORLD.get(task)
    plot(steps, losses, episodes, f"MetaWorld {task}-v3 ({args.obs}): {args.episodes} demos, {args.steps} steps "
         f"(batch {args.batch_size}), {PRESETS[args.obs].name}", png)
    result = {
        "task": f"{task}-v3",
        "obs": args.obs,
        "preset": PRESETS[args.obs].name,
        "paper_focal_success": None if paper is None else paper / 100.0,
        "demos": args.episodes,
        "train_steps": args.steps,
        "batch_size": args.batch_size,
        "train_seed": args.seed,
        "eval_episodes": len(episodes),
        "success_rate": success / 100.0,
        "mean_action_total_variation": atv,
        "final_loss": losses[-1] if losses else None,
        "seconds": {k: round(v, 1) for k, v in times.items()},
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "checkpoint": str(checkpoint),
        "episodes": episodes,
        "loss_curve": {"step": steps, "loss": losses},
    }
    (out / "result.json").write_text(json.dumps(result, indent=2))
    paper_note = (f"; the paper's FocalPolicy: {paper:.1f}% (point clouds, ~47k steps, top-5 of 20-episode "
                  "evaluations)") if paper is not None else ""
    print(f"\n[demo] {task}-v3: success rate {success:.0f}% ({sum(e['success'] for e in episodes)}/{len(episodes)} "
          f"fresh episodes, final checkpoint){paper_note}; mean ATV {atv:.4f}")
    print("[demo] wall time: " + ", ".join(f"{k[:-2]} {v / 60:.1f} min" for k, v in times.items()))
    print(f"[demo] plot: {png}\n[demo] results: {out / 'result.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
