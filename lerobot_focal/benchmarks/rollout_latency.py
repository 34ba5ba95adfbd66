"""`lerobot-focal-bench rollout`: how fast `lerobot-rollout` drives the UR-10e at the camera's real resolution.

For each input configuration (point cloud + state, image + state) it

1. records a short scripted dataset from the UR-10e twin with its camera at W x H colour + depth (LeRobot's
   `LeRobotDataset` writer, features built as `lerobot-record` builds them; the robot's `cameras.json` copied
   to `meta/` as docs/robot.md says), unless ``--checkpoint-dir`` already holds the checkpoints;
2. trains a focal checkpoint on it with the real `lerobot-train` and the CPU preset (a few steps: latency
   does not depend on the weights, only on the network and the inputs);
3. runs LeRobot's own `lerobot-rollout --strategy.type=base` on the twin at ``--fps`` for ``--duration``
   seconds, in a child process with timers around each stage of its loop
   (:mod:`lerobot_focal.benchmarks.rollout_probe`);
4. reports per stage the median and p99 per step, for the steps that call the policy network (one network
   evaluation per action chunk) and for all steps, the observation -> command time (from the robot's
   observation in hand to the arm command sent), and the achieved loop rate against the requested one.

Results: ``rollout_latency.json`` (per configuration ``resolution``, ``inputs``, ``p50_total_ms``,
``p99_total_ms`` for the policy steps, and the per-stage figures), ``.md`` and ``.png``. The first
``--warmup-s`` seconds of each rollout (first frames, first network calls) are not counted.

The twin's camera (exact ray-cast depth plus flat-shaded colour, ~15-20 ms per 848x480 frame on the CPU) renders
inside each observation by default: ``camera_read`` is that render, counted in the loop period and never in
observation -> command. A real D435i computes depth on its own chip and LeRobot's camera thread hands the loop
its latest frame, so on the arm that stage is a copy and the loop has the render's time to spare.
``--camera-fps N`` renders in the twin's own camera thread instead (``--robot.sim_camera_fps``); on a 2-core CPU
that thread competes with the policy for the cores, which a real camera does not, so it is not the default.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_focal.console import console_script, doc_parser
from lerobot_focal.figures import save_png
from lerobot_focal.robots.ur10e.twin.scene import TABLE_TOP_BOX, crop_flags

STAGES = ("get_observation", "camera_read", "inference", "preprocessor", "depth_to_cloud", "select_action",
          "network", "postprocessor", "send_action")
DEPTH_KEY = "observation.images.front_depth"
GOAL_MS = 33.0


@dataclass(frozen=True)
class Variant:
    """One input configuration: its name, what the policy reads, and the `lerobot-train` arguments for it."""

    name: str
    inputs: str
    train_args: tuple[str, ...]


def variants(crop_min: tuple[float, ...], crop_max: tuple[float, ...], image_resize: tuple[int, int],
             image_crop: tuple[int, int], state_dim: int, width: int, height: int) -> list[Variant]:
    box = crop_flags((crop_min, crop_max))
    image_features = {
        "observation.state": {"type": "STATE", "shape": [state_dim]},
        "observation.images.front": {"type": "VISUAL", "shape": [3, height, width]},
    }
    return [
        Variant("pointcloud", "512-point cloud from depth + state",
                ("--policy.use_images=false", f"--policy.depth_cloud.from_depth={DEPTH_KEY}", *box)),
        Variant("image", f"RGB (resized to {image_resize[0]}x{image_resize[1]}, crop {image_crop[0]}x{image_crop[1]}) "
                "+ state",
                ("--policy.use_images=true", f"--policy.resize_shape=[{image_resize[0]},{image_resize[1]}]",
                 f"--policy.crop_shape=[{image_crop[0]},{image_crop[1]}]",
                 f"--policy.input_features={json.dumps(image_features)}")),
    ]


# --- 1. a recorded dataset ---------------------------------------------------------------------------------
def robot_config(width: int, height: int, fps: int, calibration_dir: Path):
    from lerobot_focal.robots.ur10e.config_ur10e import UR10eConfig

    return UR10eConfig(backend="sim", sim_camera_width=width, sim_camera_height=height, control_hz=float(fps),
                       calibration_dir=calibration_dir, id="bench")


def create_robot_dataset(robot, root: Path, fps: int, repo_id: str):
    """An empty LeRobotDataset with the robot's features, built as `lerobot-record` builds them (video, depth
    included), and the observation processor that goes with it."""
    from lerobot.datasets import LeRobotDataset, aggregate_pipeline_dataset_features, create_initial_features
    from lerobot.processor import make_default_processors
    from lerobot.utils.feature_utils import combine_feature_dicts

    teleop_proc, _, obs_proc = make_default_processors()
    features = combine_feature_dicts(
        aggregate_pipeline_dataset_features(pipeline=teleop_proc,
                                            initial_features=create_initial_features(action=robot.action_features),
                                            use_videos=True),
        aggregate_pipeline_dataset_features(pipeline=obs_proc,
                                            initial_features=create_initial_features(
                                                observation=robot.observation_features),
                                            use_videos=True),
    )
    dataset = LeRobotDataset.create(repo_id, fps, root=root, robot_type=robot.name, features=features,
                                    use_videos=True)
    return dataset, obs_proc


def record_dataset(root: Path, width: int, height: int, fps: int, episodes: int, seconds: float,
                   calibration_dir: Path) -> Path:
    """Scripted TCP circles on the twin, written as `lerobot-record` writes a dataset (video, depth included)."""
    from lerobot.utils.constants import ACTION, OBS_STR
    from lerobot.utils.feature_utils import build_dataset_frame
    from lerobot.utils.robot_utils import precise_sleep

    from lerobot_focal.robots.ur10e.ur10e import UR10e

    robot = UR10e(robot_config(width, height, fps, calibration_dir))
    dataset, obs_proc = create_robot_dataset(robot, root, fps, "local/ur10e_rollout_bench")
    robot.connect()
    try:
        for episode in range(episodes):
            for i in range(int(seconds * fps)):
                start = time.perf_counter()
                phase = 2 * math.pi * i / (seconds * fps) + episode
                action = {k: 0.0 for k in robot.action_features}
                action["ee_x.vel"], action["ee_y.vel"] = 0.05 * math.cos(phase), 0.05 * math.sin(phase)
                action["gripper.pos"] = 0.5 + 0.5 * math.sin(phase)
                obs = robot.get_observation()
                robot.send_action(action)
                frame = {**build_dataset_frame(dataset.features, obs_proc(obs), prefix=OBS_STR),
                         **build_dataset_frame(dataset.features, action, prefix=ACTION), "task": "move the arm"}
                dataset.add_frame(frame)
                precise_sleep(max(0.0, 1.0 / fps - (time.perf_counter() - start)))
            dataset.save_episode()
        shutil.copy(robot.camera_infos_path, root / "meta" / "cameras.json")
    finally:
        robot.disconnect()
        dataset.finalize()
    return root


# --- 2. checkpoints ----------------------------------------------------------------------------------------
def _env(work: Path) -> dict[str, str]:
    env = dict(os.environ)
    env.update(HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1", WANDB_MODE="disabled", MUJOCO_GL="disable",
               HF_LEROBOT_CALIBRATION=str(work / "calibration"), PYTHONUNBUFFERED="1")
    return env


def _run(args: list[str], env: dict[str, str], log: Path, what: str) -> None:
    print(f"[rollout-bench] {what} (log: {log})", flush=True)
    with log.open("w") as fh:
        rc = subprocess.run(args, env=env, stdout=fh, stderr=subprocess.STDOUT, check=False).returncode
    if rc != 0:
        tail = "\n".join(log.read_text(errors="replace").splitlines()[-30:])
        raise RuntimeError(f"{what} failed (exit {rc}); last lines of {log}:\n{tail}")


def train_checkpoint(dataset: Path, out: Path, variant: Variant, steps: int, work: Path) -> Path:
    from lerobot_focal.presets import preset_path

    model = out / "checkpoints" / "last" / "pretrained_model"
    if (model / "model.safetensors").is_file():
        return model
    shutil.rmtree(out, ignore_errors=True)
    args = [console_script("lerobot-train"), f"--config_path={preset_path('cpu')}", "--policy.device=cpu",
            *variant.train_args, "--dataset.repo_id=local/ur10e_rollout_bench", f"--dataset.root={dataset}",
            f"--steps={steps}", "--batch_size=4", f"--save_freq={steps}", f"--log_freq={steps}",
            f"--output_dir={out}"]
    _run(args, _env(work), out.parent / f"train_{variant.name}.log", f"lerobot-train {variant.name} ({steps} steps)")
    return model


# --- 3. the timed rollout ----------------------------------------------------------------------------------
def timed_rollout(model: Path, width: int, height: int, fps: int, camera_fps: float, duration: float, work: Path,
                  name: str) -> Path:
    events = work / f"events_{name}.json"
    args = [sys.executable, "-m", "lerobot_focal.benchmarks.rollout_probe", str(events),
            "--strategy.type=base", f"--policy.path={model}", "--policy.device=cpu", "--robot.type=ur10e",
            "--robot.backend=sim", f"--robot.sim_camera_width={width}", f"--robot.sim_camera_height={height}",
            f"--robot.sim_camera_fps={camera_fps}", f"--robot.control_hz={fps}", f"--fps={fps}",
            f"--duration={duration}", "--task=move the arm"]
    _run(args, _env(work), work / f"rollout_{name}.log", f"lerobot-rollout {name}, {duration:.0f} s at {fps} Hz")
    return events


# --- 4. the figures ----------------------------------------------------------------------------------------
def steps_from_events(events: list[tuple[str, float, float]], warmup_s: float) -> list[dict[str, float]]:
    """One dict per loop iteration: each stage's seconds, ``start`` (loop tick), ``network`` flag and
    ``obs_to_command`` (end of get_observation -> end of send_action). Iterations start at get_observation."""
    run_start = next((s for name, s, _ in events if name == "run"), None)
    steps: list[dict[str, float]] = []
    current: dict[str, float] | None = None
    for name, start, end in events:
        if name == "get_observation":
            current = {"start": start, "obs_end": end}
            steps.append(current)
        if current is None or name == "run":
            continue
        current[name] = current.get(name, 0.0) + (end - start)
        if name == "send_action":
            current["obs_to_command"] = end - current["obs_end"]
    t0 = (run_start if run_start is not None else steps[0]["start"]) + warmup_s
    return [s for s in steps if s["start"] >= t0 and "obs_to_command" in s]


def _ms(values: list[float] | np.ndarray) -> dict[str, float]:
    arr = np.asarray(values, dtype=np.float64) * 1e3
    if arr.size == 0:
        return {"p50": float("nan"), "p99": float("nan"), "max": float("nan")}
    return {"p50": round(float(np.percentile(arr, 50)), 2), "p99": round(float(np.percentile(arr, 99)), 2),
            "max": round(float(arr.max()), 2)}


def summarise(steps: list[dict[str, float]], fps: int) -> dict:
    policy = [s for s in steps if "network" in s]
    starts = np.array([s["start"] for s in steps])
    periods = np.diff(starts)
    per_stage = {
        stage: {"policy_steps": _ms([s.get(stage, 0.0) for s in policy]),
                **({"all_steps": _ms([s.get(stage, 0.0) for s in steps])} if stage != "network" else {})}
        for stage in STAGES
    }
    total_policy = _ms([s["obs_to_command"] for s in policy])
    achieved = (len(steps) - 1) / float(starts[-1] - starts[0]) if len(steps) > 1 else float("nan")
    slowest = max((st for st in ("camera_read", "depth_to_cloud", "network", "send_action")),
                  key=lambda st: per_stage[st]["policy_steps"]["p99"])
    return {
        "steps": len(steps),
        "policy_steps": len(policy),
        "p50_total_ms": total_policy["p50"],
        "p99_total_ms": total_policy["p99"],
        "all_steps_total_ms": _ms([s["obs_to_command"] for s in steps]),
        "period_ms": _ms(periods),
        "late_periods": int(np.sum(periods > 1.5 / fps)),
        "fps_requested": fps,
        "fps_achieved": round(achieved, 2),
        "stages_ms": per_stage,
        "costliest_stage_p99": slowest,
    }


def write_report(result: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "rollout_latency.json").write_text(json.dumps(result, indent=1))
    lines = [
        f"# `lerobot-rollout` on the UR-10e twin at {result['resolution']}: observation -> command",
        "",
        f"`{result['command']}` ({result['duration_s']:.0f} s per configuration at {result['fps']} Hz, first "
        f"{result['warmup_s']:.0f} s not counted; torch threads: {result['torch_threads']}; {result['machine']}). "
        "Times are per control step, in ms; \"policy steps\" are the steps that evaluate the network (one "
        "evaluation per action chunk), the others pop the next action of the chunk.",
        "",
        f"| inputs | obs -> command p50 / p99 (policy steps) | goal p99 <= {GOAL_MS:.0f} ms | all steps p50 / p99 | "
        "loop rate achieved / requested | late periods (> 1.5 / fps) |",
        "|---|---|---|---|---|---|",
    ]
    for c in result["configurations"]:
        met = "met" if c["p99_total_ms"] <= GOAL_MS else f"missed by {c['p99_total_ms'] - GOAL_MS:.1f} ms"
        lines.append(
            f"| {c['inputs']} | {c['p50_total_ms']:.1f} / {c['p99_total_ms']:.1f} | {met} | "
            f"{c['all_steps_total_ms']['p50']:.1f} / {c['all_steps_total_ms']['p99']:.1f} | "
            f"{c['fps_achieved']:.1f} / {c['fps_requested']} Hz | {c['late_periods']} of {c['steps']} |"
        )
    lines += ["", "Per stage, policy steps, p50 / p99 ms (camera read is inside get_observation; depth -> cloud "
              "inside preprocessor; network, the one evaluation of the chunk, inside select_action, which also "
              "encodes the newest camera frame for RGB inputs; all inside inference except get_observation and "
              "send_action):", "",
              "| inputs | " + " | ".join(STAGES) + " |", "|---|" + "---|" * len(STAGES)]
    for c in result["configurations"]:
        cells = [f"{c['stages_ms'][s]['policy_steps']['p50']:.1f} / {c['stages_ms'][s]['policy_steps']['p99']:.1f}"
                 for s in STAGES]
        lines.append(f"| {c['name']} | " + " | ".join(cells) + " |")
    camera = (f"The twin's camera renders in its own thread at {result['camera_fps']:.0f} fps, as LeRobot's "
              "RealSense thread serves the arm; camera_read is the hand-over of its latest frame."
              if result["camera_fps"] > 0 else
              "The twin's camera renders inside each observation (--camera-fps 0): camera_read is that render, in "
              "the loop period but not in observation -> command.")
    lines += ["", camera + " The twin's render shares the CPU with the loop, which a real camera does not.", "",
              "![stages](rollout_latency.png)"]
    (out / "rollout_latency.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines), flush=True)
    _plot(result, out / "rollout_latency.png")


def _plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = ("camera_read", "depth_to_cloud", "preprocessor", "network", "select_action", "postprocessor",
             "send_action")
    configs = result["configurations"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    x = np.arange(len(shown))
    width = 0.8 / max(len(configs), 1)
    for i, c in enumerate(configs):
        p50 = [c["stages_ms"][s]["policy_steps"]["p50"] for s in shown]
        p99 = [c["stages_ms"][s]["policy_steps"]["p99"] for s in shown]
        axes[0].bar(x + i * width, p99, width, alpha=0.35, color=f"C{i}")
        axes[0].bar(x + i * width, p50, width, color=f"C{i}", label=f"{c['name']} (p50; light: p99)")
    axes[0].set_xticks(x + width * (len(configs) - 1) / 2, shown, rotation=30, ha="right")
    axes[0].set_ylabel("ms per policy step")
    axes[0].set_title(f"stages at {result['resolution']}")
    axes[0].legend(fontsize=8)
    for i, c in enumerate(configs):
        axes[1].bar(i, c["p50_total_ms"], 0.6, color=f"C{i}")
        axes[1].errorbar(i, c["p50_total_ms"], yerr=[[0], [c["p99_total_ms"] - c["p50_total_ms"]]], color="k",
                         capsize=6)
    axes[1].axhline(GOAL_MS, color="r", ls="--", label=f"goal p99 {GOAL_MS:.0f} ms (30 Hz)")
    axes[1].set_xticks(range(len(configs)), [c["name"] for c in configs])
    axes[1].set_ylabel("obs -> command ms (bar p50, whisker p99)")
    axes[1].set_title("policy steps, " + ", ".join(f"{c['name']} {c['fps_achieved']:.1f} Hz" for c in configs))
    axes[1].legend(fontsize=8)
    save_png(fig, path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench rollout")
    p.add_argument("--width", type=int, default=848)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--fps", type=int, default=30)
    p.add_argument("--duration", type=float, default=120.0, help="seconds of rollout per configuration")
    p.add_argument("--camera-fps", type=float, default=0.0,
                   help="0 (default): the twin renders inside each observation (in the loop period, not in "
                        "observation -> command); > 0: in its own thread at this rate, which on 2 cores competes "
                        "with the policy for the CPU as a real camera does not")
    p.add_argument("--warmup-s", type=float, default=3.0, help="seconds at the start of each rollout not counted")
    p.add_argument("--configs", nargs="+", choices=["pointcloud", "image"], default=["pointcloud", "image"])
    p.add_argument("--train-steps", type=int, default=20)
    p.add_argument("--image-resize", type=int, nargs=2, default=[120, 212], metavar=("H", "W"))
    p.add_argument("--image-crop", type=int, nargs=2, default=[108, 192], metavar=("H", "W"))
    p.add_argument("--work", type=Path, default=Path("outputs/rollout_bench"),
                   help="dataset, checkpoints and logs (reused: delete it to record and train again)")
    p.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    args = p.parse_args(argv)

    import torch

    from lerobot_focal.robots.ur10e.ur10e import UR10e

    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    cfg = robot_config(args.width, args.height, args.fps, work / "calibration")
    state_dim = sum(1 for v in UR10e(cfg).observation_features.values() if v is float)
    dataset = work / f"dataset_{args.width}x{args.height}"
    if not (dataset / "meta" / "cameras.json").is_file():
        shutil.rmtree(dataset, ignore_errors=True)
        print(f"[rollout-bench] recording 2 scripted episodes at {args.width}x{args.height} -> {dataset}", flush=True)
        record_dataset(dataset, args.width, args.height, args.fps, episodes=2, seconds=3.0,
                       calibration_dir=work / "calibration")
    chosen = [v for v in variants(*TABLE_TOP_BOX, tuple(args.image_resize),
                                  tuple(args.image_crop), state_dim, args.width, args.height)
              if v.name in args.configs]
    configurations = []
    for variant in chosen:
        model = train_checkpoint(dataset, work / f"train_{variant.name}_{args.width}x{args.height}", variant,
                                 args.train_steps, work)
        events_path = timed_rollout(model, args.width, args.height, args.fps, args.camera_fps, args.duration, work,
                                    variant.name)
        events = [tuple(e) for e in json.loads(events_path.read_text())["events"]]
        steps = steps_from_events(events, args.warmup_s)
        if not any("network" in s for s in steps):
            raise RuntimeError(f"{variant.name}: no policy step was timed; see {work / f'rollout_{variant.name}.log'}")
        configurations.append({"name": variant.name, "inputs": variant.inputs,
                               "resolution": f"{args.width}x{args.height}", **summarise(steps, args.fps)})
    result = {
        "resolution": f"{args.width}x{args.height}",
        "fps": args.fps,
        "camera_fps": args.camera_fps,
        "duration_s": args.duration,
        "warmup_s": args.warmup_s,
        "goal_p99_ms": GOAL_MS,
        "torch_threads": torch.get_num_threads(),
        "machine": f"{os.cpu_count()} CPU cores, {platform.processor() or platform.machine()}",
        "command": " ".join(["lerobot-focal-bench rollout", *(argv if argv is not None else sys.argv[1:])]),
        "configurations": configurations,
    }
    write_report(result, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
