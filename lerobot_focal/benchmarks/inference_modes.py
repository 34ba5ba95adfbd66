"""`lerobot-focal-bench inference-modes`: focal with and without real-time chunking (RTC) at simulated delays.

    lerobot-focal-bench inference-modes [--task button-press] [--delays 0 1 2 3] [--mw-episodes 20]
                                        [--twin-episodes 4] [--work outputs/inference_modes] [--out docs/benchmarks]

For MetaWorld (one task, low-dimensional inputs, the `cpu_state` preset) and the UR-10e twin (a reach task: the
TCP from a random start to a point above the cube, state only), it

1. makes a dataset: MetaWorld's scripted expert (`lerobot-focal-collect`), or a proportional TCP controller on the
   twin, recorded with LeRobot's dataset writer (features as `lerobot-record` builds them);
2. trains focal and its w/o FCO & LAS ablation (`--policy.ablation=wo_fco_las`) with the real `lerobot-train`
   (reused when ``--work`` already holds them);
3. rolls each checkpoint out with the delayed execution RTC is made for, simulated step by step: every
   ``execute`` = H control steps the policy sees observations t−1, t and computes a macro-trajectory of L
   actions; the arm keeps executing the previous chunk for ``delay`` more steps while the new one is "being
   computed", then switches to the new chunk at index ``delay``. *Without RTC* the new chunk is the network's
   own (LeRobot's engine with no guidance: "naive async"); *with RTC* it is guided towards the previous chunk's
   unexecuted actions (``prev_chunk_left_over`` = its actions from index H on, ``inference_delay`` = delay,
   LeRobot's default RTCConfig with ``execution_horizon`` = L − H), the call `lerobot-rollout
   --inference.type=rtc` makes. Delay 0 without RTC is focal's synchronous execution (`lerobot-eval`). The first
   chunk of an episode is waited for.

Per method and delay: success rate; action total variation inside chunks (mean |a_{t+1} − a_t| per dimension over
consecutive actions of the same chunk) and at chunk boundaries (the same over the switch from one chunk to the
next: the jump); the paper's ATV over the whole episode; the wall time of `predict_action_chunk` (one network
evaluation per chunk, guided or not). MetaWorld actions are its [-1, 1] commands as clipped by the env; the
twin's are its TCP velocities (m/s; the rotation rates and the gripper, constant in the demonstrations, are
sent at their constant values).

LeRobot's RTC supports only policies that declare it (pi0, pi05, smolvla, groot, evo1, molmoact2, and now
focal); LeRobot's `diffusion` does not (its `supports_rtc()` is PreTrainedPolicy's False, and `lerobot-rollout
--inference.type=rtc` refuses it), so it has no row here.

Results: ``inference_modes.json``, ``.md`` and ``.png`` under ``--out``.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_focal.console import console_script, doc_parser
from lerobot_focal.figures import save_png

#: name -> (checkpoint, guided by RTC), in table order.
METHODS = {
    "focal": ("focal", False),
    "focal_rtc": ("focal", True),
    "wo_fco_las": ("wo_fco_las", False),
    "wo_fco_las_rtc": ("wo_fco_las", True),
}
LABELS = {"focal": "focal", "focal_rtc": "focal + RTC", "wo_fco_las": "w/o FCO & LAS",
          "wo_fco_las_rtc": "w/o FCO & LAS + RTC"}
CHECKPOINT_ARGS = {"focal": (), "wo_fco_las": ("--policy.ablation=wo_fco_las",)}
TWIN_REPO = "local/ur10e_reach"
TWIN_TASK = "reach above the cube"
TWIN_GOAL = np.array([-0.65, -0.05, 0.12])  # 10 cm above the scene's red cube
TWIN_FPS = 10
TWIN_SUCCESS_M = 0.02
READING_MARKER = "<!-- reading: written by hand, kept when the tables are regenerated -->"


# --- the delayed-execution loop ----------------------------------------------------------------------------
@dataclass
class Episode:
    actions: np.ndarray  # (T, d) actions sent
    chunk_ids: np.ndarray  # (T,) which chunk each came from
    latencies_s: list[float]  # per predict_action_chunk call
    success: bool


def run_episode(env, policy, pre, post, *, seed: int, delay: int, guided: bool, max_steps: int) -> Episode:
    """One episode with chunks switched ``delay`` steps after their observation (module docstring).

    ``env``: ``reset(seed) -> obs``, ``step(action (1, d) tensor) -> (obs, done)``, ``sent`` (the last action as
    the env applied it, numpy) and ``success()``; ``obs`` is what ``pre`` takes. ``policy``: focal with an RTC
    config set, so its chunks are whole macro-trajectories."""
    import torch

    execute = int(policy.config.n_action_steps)
    if not 0 <= delay < execute:
        raise ValueError(f"delay must be in [0, {execute - 1}] (below the {execute} actions executed per chunk)")
    keys, n_obs = policy.config.used_observation_keys, int(policy.config.n_obs_steps)
    frames: deque = deque(maxlen=n_obs)
    policy.reset()
    obs = env.reset(seed)
    chunk, start, pending, arrive, cid = None, 0, None, 0, -1
    actions, ids, latencies = [], [], []
    for t in range(max_steps):
        frame = pre(obs)
        frames.extend([frame] * (n_obs if not frames else 1))
        if t % execute == 0:
            batch = {k: torch.stack([f[k] for f in frames], dim=1) for k in keys}
            leftover = chunk[0, t - start:] if guided and chunk is not None else None
            t0 = time.perf_counter()
            with torch.inference_mode():
                new = policy.predict_action_chunk(batch, inference_delay=delay, prev_chunk_left_over=leftover)
            latencies.append(time.perf_counter() - t0)
            pending, arrive = (new, t), (t if chunk is None else t + delay)
        if pending is not None and t >= arrive:
            (chunk, start), pending, cid = pending, None, cid + 1
        obs, done = env.step(post(chunk[:, t - start]))
        actions.append(env.sent)
        ids.append(cid)
        if done:
            break
    return Episode(np.stack(actions), np.array(ids), latencies, bool(env.success()))


def chunk_variation(actions: np.ndarray, chunk_ids: np.ndarray) -> dict[str, float]:
    """Mean |a_{t+1} − a_t| per dimension inside chunks and across chunk switches, and the episode's ATV."""
    if len(actions) < 2:
        return {"in_chunk": float("nan"), "boundary": float("nan"), "atv": float("nan")}
    step = np.abs(np.diff(actions, axis=0)).mean(axis=1)
    switch = chunk_ids[1:] != chunk_ids[:-1]
    return {"in_chunk": float(step[~switch].mean()) if (~switch).any() else float("nan"),
            "boundary": float(step[switch].mean()) if switch.any() else float("nan"),
            "atv": float(step.mean())}


def summarise(episodes: list[Episode]) -> dict:
    per = [chunk_variation(e.actions, e.chunk_ids) for e in episodes]
    lat = np.array([x for e in episodes for x in e.latencies_s]) * 1e3
    mean = lambda k: float(np.nanmean([p[k] for p in per]))  # noqa: E731
    return {"episodes": len(episodes), "successes": int(sum(e.success for e in episodes)),
            "success_rate": float(np.mean([e.success for e in episodes])),
            "in_chunk_tv": mean("in_chunk"), "boundary_jump": mean("boundary"), "atv": mean("atv"),
            "steps": int(sum(len(e.actions) for e in episodes)), "chunks": int(lat.size),
            "latency_ms_p50": float(np.percentile(lat, 50)), "latency_ms_p90": float(np.percentile(lat, 90))}


# --- environments ------------------------------------------------------------------------------------------
class MetaworldEpisodes:
    """One MetaWorld task with LeRobot's observation path (as `lerobot-eval` feeds a policy)."""

    def __init__(self, task: str, policy_config):
        from lerobot.envs.factory import make_env_pre_post_processors

        import lerobot_focal.envs  # noqa: F401  (registers focal_metaworld)
        from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

        self.cfg = FocalMetaworldEnvConfig(task=task, obs_type="state", env_state=True)
        self.env = self.cfg.make_single_env(task)
        self.env_pre, self.env_post = make_env_pre_post_processors(self.cfg, policy_config)
        self.max_steps = int(self.cfg.episode_length)
        self.sent, self._success = None, False

    def observation(self, raw: dict) -> dict:
        from lerobot.envs.utils import preprocess_observation

        obs = preprocess_observation({k: np.asarray(v)[None] for k, v in raw.items()})
        obs["task"] = [self.env.task_description]
        return self.env_pre(obs)

    def reset(self, seed: int) -> dict:
        raw, _ = self.env.reset(seed=seed)
        self._success = False
        return self.observation(raw)

    def step(self, action) -> tuple[dict, bool]:
        from lerobot.utils.constants import ACTION

        action = self.env_post({ACTION: action})[ACTION]
        self.sent = np.clip(action[0].cpu().numpy(), -1.0, 1.0)
        raw, _, terminated, truncated, info = self.env.step(self.sent)
        self._success = self._success or bool(info.get("is_success", False))
        return self.observation(raw), bool(terminated or truncated)

    def success(self) -> bool:
        return self._success

    def close(self) -> None:
        self.env.close()


class TwinReach:
    """The UR-10e twin in real time at 10 Hz: from a random start near home, bring the TCP above the cube.

    ``reset(seed)`` drives the arm to that episode's start (unrecorded, 2.5 s); success is the TCP within 2 cm of
    the goal at the episode's end. ``expert(obs)`` is the proportional controller that made the demonstrations."""

    def __init__(self, calibration_dir: Path, seconds: float = 4.0):
        from lerobot_focal.robots.ur10e.config_ur10e import UR10eConfig
        from lerobot_focal.robots.ur10e.ur10e import UR10e

        self.robot = UR10e(UR10eConfig(backend="sim", sim_camera_width=32, sim_camera_height=32,
                                       control_hz=float(TWIN_FPS), calibration_dir=calibration_dir, id="reach"))
        self.robot.connect()
        self.action_keys = list(self.robot.action_features)
        self.max_steps = int(seconds * TWIN_FPS)
        self.home = self.tcp(self.robot.get_observation())
        self.sent, self._last = None, None

    @staticmethod
    def tcp(obs: dict) -> np.ndarray:
        return np.array([obs["ee_x.pos"], obs["ee_y.pos"], obs["ee_z.pos"]])

    def command(self, obs: dict, goal: np.ndarray, gain: float = 2.0, speed: float = 0.15) -> dict[str, float]:
        v = gain * (goal - self.tcp(obs))
        v *= min(1.0, speed / max(float(np.linalg.norm(v)), 1e-9))
        return {**{k: 0.0 for k in self.action_keys}, "ee_x.vel": v[0], "ee_y.vel": v[1], "ee_z.vel": v[2],
                "gripper.pos": 1.0}

    def expert(self, obs: dict) -> dict[str, float]:
        return self.command(obs, TWIN_GOAL)

    def _tick(self, action: dict[str, float], start: float) -> dict:
        from lerobot.utils.robot_utils import precise_sleep

        self.robot.send_action(action)
        precise_sleep(max(0.0, 1.0 / TWIN_FPS - (time.perf_counter() - start)))
        return self.robot.get_observation()

    def start_of(self, seed: int) -> np.ndarray:
        return self.home + np.random.default_rng(seed).uniform(-0.08, 0.08, 3)

    def reset_raw(self, seed: int) -> dict:
        obs, target = self.robot.get_observation(), self.start_of(seed)
        for _ in range(int(2.5 * TWIN_FPS)):
            obs = self._tick(self.command(obs, target, gain=3.0, speed=0.25), time.perf_counter())
        self._last, self._t = obs, time.perf_counter()
        return obs

    def step_raw(self, action: dict[str, float]) -> dict:
        self._last = self._tick(action, self._t)
        self._t = time.perf_counter()
        return self._last

    def success(self) -> bool:
        return bool(np.linalg.norm(self.tcp(self._last) - TWIN_GOAL) < TWIN_SUCCESS_M)

    def close(self) -> None:
        self.robot.disconnect()


class TwinPolicyEnv:
    """`TwinReach` with the observation and action path of LeRobot's rollout engines."""

    def __init__(self, twin: TwinReach, policy_config):
        from lerobot.utils.feature_utils import hw_to_dataset_features

        self.twin, self.max_steps = twin, twin.max_steps
        self.features = hw_to_dataset_features(twin.robot.observation_features, "observation")
        self.sent = None

    def observation(self, raw: dict) -> dict:
        import torch
        from lerobot.policies.utils import prepare_observation_for_inference
        from lerobot.utils.feature_utils import build_dataset_frame

        frame = build_dataset_frame(self.features, raw, prefix="observation")
        obs = prepare_observation_for_inference(frame, torch.device("cpu"), TWIN_TASK, self.twin.robot.name)
        obs["task"] = [TWIN_TASK]
        return obs

    def reset(self, seed: int) -> dict:
        return self.observation(self.twin.reset_raw(seed))

    def step(self, action) -> tuple[dict, bool]:
        """The task's command is the TCP velocity: the policy's x, y, z velocities are sent; the dimensions the
        demonstrations hold constant (rotation rates 0, gripper open) are sent at that constant, not the
        policy's output there (a one-step flow's residual noise on dimensions the data never moved, ±0.1 rad/s
        and ±0.5 of the gripper range after 1000 steps, which the twin would execute as wrist rotations)."""
        command = action[0].cpu().numpy().astype(np.float64)
        self.sent = command[:3]
        held = {**{k: 0.0 for k in self.twin.action_keys}, "gripper.pos": 1.0}
        held.update({k: float(v) for k, v in zip(self.twin.action_keys[:3], self.sent, strict=True)})
        raw = self.twin.step_raw(held)
        return self.observation(raw), False

    def success(self) -> bool:
        return self.twin.success()


def record_twin(root: Path, episodes: int, calibration_dir: Path) -> Path:
    """Expert reach episodes on the twin, one per seed 0..episodes−1, as a LeRobotDataset."""
    from lerobot.utils.constants import ACTION, OBS_STR
    from lerobot.utils.feature_utils import build_dataset_frame

    from .rollout_latency import create_robot_dataset

    twin = TwinReach(calibration_dir)
    dataset, obs_proc = create_robot_dataset(twin.robot, root, TWIN_FPS, TWIN_REPO)
    try:
        for seed in range(episodes):
            obs = twin.reset_raw(seed)
            for _ in range(twin.max_steps):
                action = twin.expert(obs)
                dataset.add_frame({**build_dataset_frame(dataset.features, obs_proc(obs), prefix=OBS_STR),
                                   **build_dataset_frame(dataset.features, action, prefix=ACTION), "task": TWIN_TASK})
                obs = twin.step_raw(action)
            dataset.save_episode()
    finally:
        twin.close()
        dataset.finalize()
    return root


# --- data and checkpoints ----------------------------------------------------------------------------------
def _env_vars(work: Path) -> dict[str, str]:
    return {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "WANDB_MODE": "disabled",
            "MUJOCO_GL": "disable", "LEROBOT_FOCAL_FAST_READER": "1", "OMP_NUM_THREADS": "1",
            "HF_LEROBOT_CALIBRATION": str(work / "calibration")}


def _run(args: list[str], work: Path, log: Path, what: str) -> None:
    print(f"[inference-modes] {what} (log: {log})", flush=True)
    with log.open("w") as fh:
        rc = subprocess.run(args, env=_env_vars(work), stdout=fh, stderr=subprocess.STDOUT, check=False).returncode
    if rc != 0:
        tail = "\n".join(log.read_text(errors="replace").splitlines()[-30:])
        raise RuntimeError(f"{what} failed (exit {rc}); last lines of {log}:\n{tail}")


def train(dataset: Path, repo_id: str, out: Path, name: str, steps: int, extra: tuple[str, ...]) -> Path:
    """A `lerobot-train` run of the cpu_state preset (reused when its last checkpoint exists)."""
    from lerobot_focal.presets import preset_path

    model = out / "checkpoints" / "last" / "pretrained_model"
    if (model / "model.safetensors").is_file():
        return model
    shutil.rmtree(out, ignore_errors=True)
    _run([console_script("lerobot-train"), f"--config_path={preset_path('cpu_state')}",
          f"--dataset.repo_id={repo_id}", f"--dataset.root={dataset}", f"--output_dir={out}", f"--steps={steps}",
          f"--save_freq={steps}", "--log_freq=100", "--seed=0", *CHECKPOINT_ARGS[name], *extra],
         out.parent, out.parent / f"train_{name}.log", f"lerobot-train {name} ({steps} steps)")
    return model


def metaworld_checkpoints(work: Path, task: str, steps: int) -> dict[str, Path]:
    root = work / "data"
    if not (root / "meta" / "info.json").is_file():
        _run([sys.executable, "-m", "lerobot_focal.datasets.making.collect", "--root", str(root), "--tasks", task,
              "--repo_id", f"local/metaworld_{task}", "--episodes", "10", "--obs_types", "state,env_state"],
             work, work / "collect.log", f"lerobot-focal-collect {task} (10 expert episodes)")
    return {n: train(root, f"local/metaworld_{task}", work / n, n, steps, ()) for n in CHECKPOINT_ARGS}


def twin_checkpoints(work: Path, episodes: int, steps: int) -> dict[str, Path]:
    root = work / "data"
    if not (root / "meta" / "info.json").is_file():
        shutil.rmtree(root, ignore_errors=True)
        print(f"[inference-modes] recording {episodes} expert reach episodes on the twin", flush=True)
        record_twin(root, episodes, work / "calibration" / "robots" / "ur10e")
    # State only: the preset reads object poses, which the twin does not observe; no camera.
    extra = ("--policy.use_env_state=false", "--policy.use_images=false")
    return {n: train(root, TWIN_REPO, work / n, n, steps, extra) for n in CHECKPOINT_ARGS}


# --- the benchmark -----------------------------------------------------------------------------------------
def evaluate(make_env, checkpoints: dict[str, Path], methods: list[str], delays: list[int], seeds: list[int],
             label: str) -> dict:
    from lerobot.policies.rtc.configuration_rtc import RTCConfig

    from .grid.analyze import load_policy

    results: dict[str, dict] = {}
    for name in methods:
        ckpt, guided = METHODS[name]
        policy, pre, post = load_policy(checkpoints[ckpt])
        cfg = policy.config
        # LeRobot's default RTC settings, with the leftover's length (L − H) as the execution horizon.
        cfg.rtc_config = RTCConfig(execution_horizon=cfg.horizon - cfg.n_action_steps)
        policy.init_rtc_processor()
        env = make_env(cfg)
        results[name] = {}
        for delay in delays:
            t0 = time.perf_counter()
            eps = [run_episode(env, policy, pre, post, seed=s, delay=delay, guided=guided, max_steps=env.max_steps)
                   for s in seeds]
            results[name][str(delay)] = summarise(eps)
            r = results[name][str(delay)]
            print(f"[inference-modes] {label} {LABELS[name]:<20} delay {delay}: success {r['successes']}/"
                  f"{r['episodes']}, in-chunk TV {r['in_chunk_tv']:.4f}, jump {r['boundary_jump']:.4f}, "
                  f"{r['latency_ms_p50']:.1f} ms/chunk ({time.perf_counter() - t0:.0f} s)", flush=True)
        if hasattr(env, "close"):
            env.close()
    return results


def write_report(result: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "inference_modes.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = [
        "# Inference modes: focal with and without real-time chunking at simulated delays",
        "",
        f"Command: `{result['command']}` ({result['wall_min']:.0f} min on {result['machine']}).",
        "",
        "What ran (`lerobot_focal/benchmarks/inference_modes.py`): per environment a dataset, focal and its w/o FCO & "
        "LAS ablation trained once by `lerobot-train` (cpu_state preset, 32/64/128 U-Net), then the same episodes "
        "(same seeds) for every method and delay. Every H = 4 control steps the policy computes a macro-trajectory "
        "of L = 12 actions from observations t−1, t; the arm executes the previous chunk for `delay` more steps, "
        "then the new chunk from index `delay`. *+ RTC*: the new chunk is guided towards the previous chunk's "
        "unexecuted actions, the call `lerobot-rollout --inference.type=rtc` makes (LeRobot's default RTCConfig, "
        "execution horizon 8 = L − H; one network evaluation, so the guidance is the soft-masked blend described "
        "in `lerobot_focal/policy/rtc.py`). Without RTC the switch is to the network's own chunk. Delay 0 without "
        "RTC is focal's synchronous execution.",
        "",
    ]
    for block in result["environments"].values():
        lines += [f"## {block['title']}", "", block["scale"], "",
                  "| method | delay | success | in-chunk TV | jump at chunk boundary | ATV | ms / chunk (p50, p90) |",
                  "|---|---|---|---|---|---|---|"]
        for name, by_delay in block["results"].items():
            for delay, r in by_delay.items():
                lines.append(f"| {LABELS[name]} | {delay} | {r['successes']}/{r['episodes']} | "
                             f"{r['in_chunk_tv']:.4f} | {r['boundary_jump']:.4f} | {r['atv']:.4f} | "
                             f"{r['latency_ms_p50']:.2f}, {r['latency_ms_p90']:.2f} |")
        lines.append("")
    md = out / "inference_modes.md"
    # The hand-written reading of the numbers, below the marker, survives a regeneration of the tables.
    old = md.read_text() if md.is_file() else ""
    reading = old[old.index(READING_MARKER):] if READING_MARKER in old else f"{READING_MARKER}\n"
    md.write_text("\n".join(lines) + "\n" + reading)
    _plot(result, out / "inference_modes.png")


def _plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = list(result["environments"].items())
    fig, axes = plt.subplots(len(envs), 3, figsize=(13, 3.6 * len(envs)), squeeze=False)
    for row, (_, block) in enumerate(envs):
        for col, (key, title) in enumerate((("success_rate", "success rate"), ("boundary_jump", "jump at boundary"),
                                            ("in_chunk_tv", "in-chunk TV"))):
            ax = axes[row][col]
            for name, by_delay in block["results"].items():
                delays = [int(d) for d in by_delay]
                ax.plot(delays, [by_delay[str(d)][key] for d in delays], marker="o", label=LABELS[name],
                        linestyle="--" if name.endswith("_rtc") else "-")
            ax.set_xlabel("simulated inference delay (control steps)")
            ax.set_title(f"{block['title']}: {title}", fontsize=9)
            ax.set_xticks(delays)
        axes[row][0].legend(fontsize=8)
    save_png(fig, path)


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "lerobot-focal-bench inference-modes")
    parser.add_argument("--task", default="button-press", help="MetaWorld task (default: button-press)")
    parser.add_argument("--delays", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(METHODS))
    parser.add_argument("--mw-episodes", type=int, default=20, help="MetaWorld evaluation episodes per cell")
    parser.add_argument("--mw-train-steps", type=int, default=1500)
    parser.add_argument("--twin-episodes", type=int, default=4, help="twin evaluation episodes per cell")
    parser.add_argument("--twin-demos", type=int, default=12)
    parser.add_argument("--twin-train-steps", type=int, default=1000)
    parser.add_argument("--envs", nargs="+", choices=["metaworld", "twin"], default=["metaworld", "twin"])
    parser.add_argument("--threads", type=int, default=1, help="torch threads for the rollouts")
    parser.add_argument("--work", type=Path, default=Path("outputs/inference_modes"))
    parser.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    environments = {}
    if "metaworld" in args.envs:
        work = args.work / f"metaworld_{args.task}"
        work.mkdir(parents=True, exist_ok=True)
        ckpts = metaworld_checkpoints(work, args.task, args.mw_train_steps)
        seeds = [1000 + i for i in range(args.mw_episodes)]  # fresh placements (the demos used seeds 0..)
        environments["metaworld"] = {
            "title": f"MetaWorld {args.task}",
            "scale": f"10 expert demos, {args.mw_train_steps} training steps at batch 64, {args.mw_episodes} "
                     f"evaluation episodes per cell (seeds 1000…), up to 200 steps each; state + object poses.",
            "results": evaluate(lambda cfg: MetaworldEpisodes(args.task, cfg), ckpts, args.methods, args.delays,
                                seeds, "MetaWorld"),
        }
    if "twin" in args.envs:
        work = args.work / "twin_reach"
        work.mkdir(parents=True, exist_ok=True)
        ckpts = twin_checkpoints(work, args.twin_demos, args.twin_train_steps)
        twin = TwinReach(work / "calibration" / "robots" / "ur10e")
        try:
            environments["twin"] = {
                "title": "UR-10e twin, reach above the cube",
                "scale": f"{args.twin_demos} expert demos (proportional TCP controller, 4 s at {TWIN_FPS} Hz), "
                         f"{args.twin_train_steps} training steps at batch 64, {args.twin_episodes} evaluation "
                         f"episodes per cell (start offsets from seeds 100…, in real time), state only, the "
                         "policy's x, y, z TCP velocities sent (rotation rates and gripper held at the "
                         f"demonstrations' constants); success: TCP within {TWIN_SUCCESS_M * 100:.0f} cm of "
                         "the goal after 4 s.",
                "results": evaluate(lambda cfg: TwinPolicyEnv(twin, cfg), ckpts, args.methods, args.delays,
                                    [100 + i for i in range(args.twin_episodes)], "twin"),
            }
        finally:
            twin.close()
    result = {
        "command": "lerobot-focal-bench inference-modes " + " ".join(argv if argv is not None else sys.argv[1:]),
        "machine": f"{os.cpu_count()} CPU cores ({platform.machine()}), torch threads {args.threads}",
        "wall_min": (time.perf_counter() - t0) / 60,
        "environments": environments,
    }
    write_report(result, args.out)
    print(f"[inference-modes] wrote {args.out / 'inference_modes.md'}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
