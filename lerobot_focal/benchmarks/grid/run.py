"""One grid run: `lerobot-train` with LeRobot's periodic evaluation, then the checkpoint metrics.

Everything is a real LeRobot process: `lerobot-train` trains with the method's arguments and, every K steps,
evaluates N episodes in ``focal_metaworld`` (its own ``--env_eval_freq`` loop); the env writes one JSON line per
episode (success, length, ATV) to ``eval_episodes.jsonl``; then ``analyze`` measures the final checkpoint.
A run is a plain function of a picklable ``RunSpec`` so the local executor and Ray tasks call the same code.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path

from lerobot_focal.console import console_script

from .demos import collect_task_data
from .grid_presets import GridPreset
from .methods import METHODS, is_camera
from .metrics import eval_curve, top_k_mean
from .processes import RunFailed, refuse_if_stopping, run_logged
from .results import RunRecord
from .resume import (
    earlier_segments,
    find_resume_point,
    forget_resume,
    prepare_resume,
    prune_checkpoints,
    resume_command,
    seeded_episodes,
    seeded_records,
    start_segment,
)
from .seeds import FINAL_EVAL_SEED, fresh_offset
from .specs import RunSpec, checkpoint_of

UPDATE_RE = re.compile(r"\bupdt_s:([0-9.]+)")


def _env_args(spec: RunSpec, metrics_path: Path) -> list[str]:
    p = spec.preset
    camera = is_camera(spec.obs_type)
    # LeRobot renders evaluation episodes to video; the grid needs none (and no blank frames to encode), unless
    # the policy observes the camera: then frames are its input, at the size its demos were recorded.
    size = p.image_size if camera else 64
    return [
        "--env.type=focal_metaworld",
        f"--env.task={spec.task}",
        f"--env.obs_type={spec.obs_type}",
        f"--env.env_state={str(p.env_state and not camera).lower()}",
        f"--env.episode_length={p.episode_length}",
        f"--env.observation_width={size}",
        f"--env.observation_height={size}",
        f"--env.render_videos={str(camera).lower()}",
        f"--env.metrics_path={metrics_path}",
        "--eval.use_async_envs=false",
        *(_cloud_args(p) if spec.obs_type == "pointcloud" else []),
    ]


def _cloud_args(p: GridPreset) -> list[str]:
    """The evaluation env's cloud: the preset's evaluation point count and table crop (None: keep the table)."""
    clearance = "null" if p.table_clearance is None else p.table_clearance
    return [f"--env.num_points={p.eval_points}", f"--env.table_clearance={clearance}"]


def final_eval_command(spec: RunSpec, checkpoint: Path, name: str = "final") -> list[str]:
    """`lerobot-eval` of the final checkpoint on `final_episodes` fresh episodes (see FINAL_EVAL_SEED).

    ``name`` prefixes its episode file, output folder and job (another evaluation of the same episodes, e.g.
    with the online weights, keeps its own files)."""
    p = spec.preset
    out = spec.run_dir
    return [
        console_script("lerobot-eval"),
        f"--policy.path={checkpoint}",
        f"--policy.device={p.device}",
        *_env_args(spec, out / f"{name}_episodes.jsonl"),
        f"--eval.n_episodes={p.final_episodes}",
        f"--eval.batch_size={min(p.final_episodes, 25)}",
        f"--seed={FINAL_EVAL_SEED + 1000 * spec.seed}",
        f"--output_dir={out / f'{name}_eval'}",
        f"--job_name={name}_eval",
    ]


def train_command(spec: RunSpec) -> list[str]:
    p = spec.preset
    out = spec.run_dir
    return [
        console_script("lerobot-train"),
        *METHODS[spec.method].train_args(p),
        f"--dataset.repo_id={spec.data.train_repo_id}",
        f"--dataset.root={spec.data.train_root}",
        f"--output_dir={out / 'train'}",
        f"--job_name={spec.task}_{spec.method}_s{spec.seed}",
        f"--seed={spec.seed}",
        f"--steps={p.steps}",
        f"--batch_size={p.batch_size}",
        "--num_workers=0",
        f"--save_freq={p.eval_every}",  # a checkpoint at every evaluation: an interrupted run resumes (resume.py)
        f"--log_freq={max(p.eval_every // 2, 1)}",
        "--wandb.enable=false",
        # LeRobot's own periodic evaluation, in the plugin's env (same seeds at every evaluation unless "fresh").
        *_env_args(spec, out / "eval_episodes.jsonl"),
        f"--env_eval_freq={p.eval_every}",
        # "fresh": the env offsets LeRobot's reset seeds by this plus the evaluation episodes already recorded,
        # so every evaluation (and every training seed) draws new placements, as DP3's runner does (seeds.py).
        *([f"--env.fresh_reset_seeds={fresh_offset(p, spec.seed)}"] if p.periodic_eval == "fresh" else []),
        f"--eval.n_episodes={p.eval_episodes}",
        f"--eval.batch_size={p.eval_episodes}",
        *p.extra_train_args,
    ]


#: glibc malloc settings for a run's processes: serve every allocation from the heap and keep freed memory for
#: reuse, instead of mapping (and page-faulting in, zero-filled) each large tensor anew. The point-cloud
#: encoder's activations are up to 64 MB a layer at batch 64 (2 frames × 512 points × 256 channels), at or above
#: glibc's largest mmap threshold (32 MB), so by default every training step maps and unmaps them: a focal step
#: on point clouds takes 2× as long, with bit-identical losses and weights either way (see docs/benchmarks.md).
#: A value already in the environment wins.
MALLOC_ENV: dict[str, str] = {"MALLOC_MMAP_MAX_": "0", "MALLOC_TRIM_THRESHOLD_": str(4 << 30)}


def child_env(preset: GridPreset) -> dict[str, str]:
    """Environment of a run's LeRobot processes: offline, no W&B, heap-only malloc, the preset's torch threads.

    An ``OMP_NUM_THREADS`` already in the environment wins over the preset's, as the malloc settings do: a run
    alone on the machine (``--jobs 1``) may use every core. Threads change a run's speed, not what it computes;
    each record keeps the count (``torch_threads``)."""
    env = {**MALLOC_ENV, **os.environ, "WANDB_MODE": "disabled", "HF_HUB_OFFLINE": "1",
           "LEROBOT_FOCAL_FAST_READER": "1"}
    if preset.num_threads and "OMP_NUM_THREADS" not in os.environ:
        env["OMP_NUM_THREADS"] = env["MKL_NUM_THREADS"] = str(preset.num_threads)
    return env


def _evaluation_progress(spec: RunSpec) -> Callable[[], None]:
    """A callable that logs each periodic evaluation the run completed since its last call: a run takes up to
    an hour on a CPU, and this is how its progress shows in the grid's output."""
    p = spec.preset
    total = p.steps // p.eval_every
    shown = len(seeded_episodes(spec.run_dir)) // p.eval_episodes

    def report() -> None:
        nonlocal shown
        episodes = seeded_episodes(spec.run_dir)
        for i in range(shown, len(episodes) // p.eval_episodes):
            block = episodes[i * p.eval_episodes : (i + 1) * p.eval_episodes]
            logging.info("%s: evaluation %d/%d (step %d): %.0f %% success", spec.key, i + 1, total,
                         (i + 1) * p.eval_every, 100 * sum(e["success"] for e in block) / len(block))
            shown = i + 1

    return report


def resumable_step(spec: RunSpec) -> int | None:
    """The step an interrupted run would continue from, None if it would start over (or never started)."""
    p = spec.preset
    point = find_resume_point(spec.run_dir, train_command(spec), p.eval_every, p.eval_episodes)
    return point.step if point else None


def run_one(spec: RunSpec) -> RunRecord:
    """Train, evaluate and measure one (task, method, seed); returns its result record. Raises RunFailed.

    A run interrupted earlier continues from its newest usable checkpoint (see ``resume``), else starts over."""
    refuse_if_stopping()  # before anything is deleted, logged or collected
    out = spec.run_dir
    p = spec.preset
    command = train_command(spec)
    point = find_resume_point(out, command, p.eval_every, p.eval_episodes) if out.exists() else None
    if point is not None:
        prepare_resume(out, point)
    else:
        if out.exists():
            shutil.rmtree(out)  # an interrupted attempt with nothing to continue from: start it over
        out.mkdir(parents=True)
    started_at = time.strftime("%Y-%m-%dT%H:%M:%S")
    resumed_note = f" resumed from step {point.step}" if point else ""
    with open(spec.work / "attempts.log", "a") as f:  # every start of every run, kept across retries
        f.write(f"{started_at} {spec.key} pid={os.getpid()}{resumed_note}\n")
    if point:
        logging.info("%s: continuing from its checkpoint at step %d of %d", spec.key, point.step, p.steps)
    env = child_env(p)
    collect_task_data(spec.data, p, None if spec.obs_type == p.obs_type else spec.obs_type, spec.work / "logs")

    start_segment(out, command, point.step if point else 0)
    t0 = time.perf_counter()
    if point is None or point.step < p.steps:  # else only the final evaluation and the analysis were left
        progress = _evaluation_progress(spec)

        def housekeeping() -> None:
            progress()
            prune_checkpoints(out, keep=2, keep_from=spec.keep_checkpoints_from)

        try:
            run_logged(command if point is None else resume_command(command[0], point), out / "train.log", env,
                       "lerobot-train", poll=housekeeping)
        except RunFailed as err:
            if point is not None:  # a resume that fails is not tried again: the next attempt starts over
                forget_resume(out)
                raise RunFailed(f"resuming from step {point.step} failed (the next attempt starts the run over): "
                                f"{err}") from err
            raise
        progress()  # the evaluations since the last poll
    prune_checkpoints(out, keep=1, keep_from=spec.keep_checkpoints_from)
    kept_s, spans, lost_s, resumed_from = earlier_segments(out)
    wall_s = kept_s + time.perf_counter() - t0

    curve = eval_curve(seeded_episodes(out), p.eval_episodes, p.eval_every)
    if len(curve) != p.steps // p.eval_every:
        raise RunFailed(f"expected {p.steps // p.eval_every} evaluations, found {len(curve)} in {out}")
    updates = [float(x) for x in UPDATE_RE.findall((out / "train.log").read_text(errors="replace"))]

    checkpoint = checkpoint_of(out)
    final: dict = {}
    if p.final_episodes:
        t1 = time.perf_counter()
        for stale in (out / "final_episodes.jsonl", out / "final_eval"):  # of an interrupted final evaluation
            shutil.rmtree(stale) if stale.is_dir() else stale.unlink(missing_ok=True)
        run_logged(final_eval_command(spec, checkpoint), out / "final_eval.log", env, "final lerobot-eval")
        fresh = seeded_records(out / "final_episodes.jsonl")
        if len(fresh) != p.final_episodes:
            raise RunFailed(f"expected {p.final_episodes} final episodes, found {len(fresh)} in {out}")
        final = {
            "success_fresh": sum(e["success"] for e in fresh) / len(fresh),
            "atv_fresh": sum(e["action_total_variation"] for e in fresh) / len(fresh),
            "fresh_episodes": len(fresh),
            "final_eval_s": time.perf_counter() - t1,
        }
    analysis_path = out / "analysis.json"
    run_logged(
        [sys.executable, "-m", "lerobot_focal.benchmarks.grid.analyze", str(checkpoint), str(spec.data.heldout_root),
         spec.data.heldout_repo_id, str(analysis_path), "--device", p.device],
        out / "analyze.log", env, "checkpoint analysis",
    )
    analysis = json.loads(analysis_path.read_text())
    successes = [c["success"] for c in curve]
    finished_at = time.strftime("%Y-%m-%dT%H:%M:%S")
    return RunRecord(
        key=spec.key,
        status="ok",
        task=spec.task,
        method=spec.method,
        seed=spec.seed,
        preset=p.name,
        success_top_k=top_k_mean(successes, p.top_k),
        periodic_eval=p.periodic_eval,
        success_final=successes[-1],
        atv=curve[-1]["atv"],
        curve=curve,
        **final,
        **analysis,
        update_s_per_step=(sum(updates) / len(updates)) if updates else None,
        torch_threads=int(env["OMP_NUM_THREADS"]) if env.get("OMP_NUM_THREADS", "").isdigit() else None,
        wall_s=wall_s,
        run_dir=str(out),
        started_at=started_at,
        finished_at=finished_at,
        **({"resumed_from_steps": resumed_from, "lost_s": lost_s, "spans": [*spans, [started_at, finished_at]]}
           if resumed_from else {}),
    )


def failure_record(spec: RunSpec, error: BaseException, attempts: int) -> RunRecord:
    return RunRecord(key=spec.key, status="failed", task=spec.task, method=spec.method, seed=spec.seed,
                     preset=spec.preset.name, attempts=attempts, error=str(error)[-3000:],
                     finished_at=time.strftime("%Y-%m-%dT%H:%M:%S"))
