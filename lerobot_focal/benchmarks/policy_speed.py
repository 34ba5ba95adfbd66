"""Inference latency and training-step cost of `focal` against its own U-Net, LeRobot's `diffusion` and `act`.

    lerobot-focal-bench speed                       # CPU preset and paper size, on the machine it runs on
    lerobot-focal-bench speed --sizes cpu --device cuda

What is compared, at equal U-Net size (down_dims, kernel, groups, n_obs = 2; horizon 12 for focal, 16 for diffusion,
the smallest LeRobot's diffusion accepts with three levels) and with the same
observation (state 9-d + environment state 39-d, the only kind both policies take without extra encoders):
- `focal` `predict_action_chunk` (obs encoder + one U-Net evaluation, batch 1) against one bare forward of the
  same U-Net with a precomputed condition — the overhead of the policy around the network (goal ≤ 1.1×);
- LeRobot's `diffusion` `generate_actions` with DDIM 10 and DDPM 100 steps at the same U-Net size;
- LeRobot's `act` `predict_action_chunk` (one transformer pass for a 50-action chunk, the grid's chunk) on the same
  observation, timed in the same round-robin as focal's chunk so their ratio holds on a loaded machine; its width
  is the grid's for the CPU sizes (128 / 800) and ACT's default (512 / 3200) at paper size;
- one training step (forward, backward, AdamW step, EMA update) of `focal` against a plain flow-matching step
  of the same network (goal ≤ 1.6×): focal pays one extra no-grad evaluation of the EMA target.
Timings are medians over repeats measured in the same process; ratios are what to compare across machines.
"""

from __future__ import annotations

import json
import platform
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from lerobot_focal.figures import save_png

#: U-Net down_dims per size: ``grid`` is the CPU grid presets' (cpu_plateau, cpu_fair), ``cpu`` the CPU training
#: preset's, ``paper`` the paper's.
SIZES = {"grid": (32, 64, 128), "cpu": (64, 128, 256), "paper": (512, 1024, 2048)}
STATE_DIM, ENV_DIM, ACTION_DIM = 9, 39, 4


@dataclass
class Row:
    size: str
    params_m: float
    what: str
    median_ms: float
    ratio: float | None = None
    ratio_to: str = ""


def benchmark_features():
    from lerobot.configs.types import FeatureType, PolicyFeature

    inputs = {
        "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,)),
        "observation.environment_state": PolicyFeature(type=FeatureType.ENV, shape=(ENV_DIM,)),
    }
    return inputs, {"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))}


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def time_ms(fns: dict[str, object], device: str, repeats: int, warmup: int = 2) -> dict[str, float]:
    """Median milliseconds per call of each function, calls interleaved round-robin so that load from other
    processes on a shared machine hits every contender alike and their ratio stays meaningful."""
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    _sync(device)
    samples: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            _sync(device)
            samples[name].append((time.perf_counter() - t0) * 1e3)
    return {name: statistics.median(v) for name, v in samples.items()}


def build_focal(down_dims, device: str, inputs: dict | None = None):
    """A benchmark focal at U-Net size `down_dims` on `inputs` (default: state + environment state; the object
    poses condition the policy whenever they are among the inputs)."""
    from lerobot_focal.policy import FocalConfig, FocalPolicy

    default_inputs, outputs = benchmark_features()
    inputs = default_inputs if inputs is None else inputs
    cfg = FocalConfig(device=device, down_dims=down_dims, use_env_state="observation.environment_state" in inputs,
                      input_features=inputs, output_features=outputs)
    return FocalPolicy(cfg).to(device)


def build_diffusion(down_dims, device: str, scheduler: str, steps: int):
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

    inputs, outputs = benchmark_features()
    cfg = DiffusionConfig(
        device=device,
        down_dims=down_dims,
        # LeRobot's diffusion needs horizon % 2**len(down_dims) == 0, so 16 (its default) rather than focal's 12.
        horizon=16,
        n_obs_steps=2,
        n_action_steps=4,
        noise_scheduler_type=scheduler,
        num_train_timesteps=100,
        num_inference_steps=steps,
        input_features=inputs,
        output_features=outputs,
    )
    return DiffusionPolicy(cfg).to(device)


#: The grid preset whose ACT stands beside each U-Net size: the CPU grid's (width 128 / 800) for the CPU sizes,
#: the paper preset's (ACT's default width, 512 / 3200) at paper size.
ACT_PRESET = {"grid": "cpu_fair", "cpu": "cpu_fair", "paper": "paper"}


def build_act(size: str, device: str):
    """LeRobot's ACT as the grid's ``ACT_PRESET[size]`` builds it (chunk 50 executed whole, the preset's width)."""
    from lerobot.policies.act.modeling_act import ACTPolicy

    from lerobot_focal.benchmarks.grid.grid_presets import PRESETS
    from lerobot_focal.benchmarks.grid.methods import act_config

    inputs, outputs = benchmark_features()
    return ACTPolicy(act_config(PRESETS[ACT_PRESET[size]], inputs, outputs, device=device)).to(device)


def _obs(batch: int, device: str) -> dict[str, Tensor]:
    return {
        "observation.state": torch.randn(batch, 2, STATE_DIM, device=device),
        "observation.environment_state": torch.randn(batch, 2, ENV_DIM, device=device),
    }


def _one_pass_ms(down_dims, device: str, repeats: int, obs: dict[str, Tensor], act) -> tuple[float, dict]:
    """(U-Net parameters in millions, median ms of ``bare`` U-Net forward, focal ``chunk`` and the ACT policy
    ``act``'s chunk, all in one round-robin); focal is freed on return."""
    focal = build_focal(down_dims, device).eval()
    params = sum(p.numel() for p in focal.model.velocity_net.parameters()) / 1e6
    net = focal.ema_model
    cond = net.encode(obs)
    x = torch.randn(1, focal.config.horizon, ACTION_DIM, device=device)
    t = torch.full((1,), 0.01, device=device)
    latest = {k: v[:, -1] for k, v in obs.items()}  # ACT reads one observation step
    fns = {"bare": lambda: net.velocity(x, t, cond), "chunk": lambda: focal.predict_action_chunk(obs),
           "act": lambda: act.predict_action_chunk(latest)}
    with torch.no_grad():
        return params, time_ms(fns, device, repeats)


def _diffusion_ms(down_dims, device: str, sched: str, steps: int, repeats: int, obs: dict[str, Tensor]) -> float:
    """Median ms of one LeRobot diffusion chunk; the model is freed on return."""
    dp = build_diffusion(down_dims, device, sched, steps).eval()
    with torch.no_grad():
        return time_ms({"dp": lambda: dp.diffusion.generate_actions(obs)}, device, repeats, warmup=1)["dp"]


def inference_rows(size: str, device: str, repeats: int, ddpm: bool) -> list[Row]:
    down_dims = SIZES[size]
    obs = _obs(1, device)
    act = build_act(size, device).eval()
    act_params = sum(p.numel() for p in act.parameters()) / 1e6
    params, ms = _one_pass_ms(down_dims, device, repeats, obs, act)
    chunk = ms["chunk"]
    rows = [
        Row(size, params, "bare U-Net forward", ms["bare"]),
        Row(size, params, "focal predict_action_chunk (1 NFE)", chunk, chunk / ms["bare"], "bare"),
        Row(size, act_params, f"ACT predict_action_chunk ({act.config.chunk_size} actions, width "
                              f"{act.config.dim_model}/{act.config.dim_feedforward})", ms["act"],
            ms["act"] / chunk, "focal"),
    ]
    del act
    variants = [("DDIM", 10)] + ([("DDPM", 100)] if ddpm else [])
    for sched, steps in variants:
        ms = _diffusion_ms(down_dims, device, sched, steps, max(3, repeats // (4 if steps > 10 else 1)), obs)
        rows.append(Row(size, params, f"diffusion {sched} {steps}", ms, ms / chunk, "focal"))
    return rows


def training_rows(size: str, device: str, repeats: int, batch: int) -> list[Row]:
    from lerobot_focal.policy.objective import interpolate

    focal = build_focal(SIZES[size], device).train()
    params = sum(p.numel() for p in focal.model.velocity_net.parameters()) / 1e6
    opt = torch.optim.AdamW(focal.get_optim_params(), lr=1e-4)
    data = {**_obs(batch, device), "action": torch.randn(batch, focal.config.horizon, ACTION_DIM, device=device)}

    def focal_step():
        loss, _ = focal.forward(data)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        focal.update()

    def plain_fm_step():
        # Rectified flow matching with the same network and optimizer: x_t = (1-t)·x0 + t·x1, v* = x1 − x0.
        obs = {k: data[k] for k in ("observation.state", "observation.environment_state")}
        cond = focal.model.encode(obs)
        m1 = data["action"]
        m0 = torch.randn_like(m1)
        tt = torch.rand(batch, device=device)
        v = focal.model.velocity(interpolate(m0, m1, tt), tt, cond)
        loss = torch.nn.functional.mse_loss(v, m1 - m0)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    ms = time_ms({"plain": plain_fm_step, "focal": focal_step}, device, repeats, warmup=1)
    plain, ours = ms["plain"], ms["focal"]
    return [
        Row(size, params, f"plain flow-matching train step (batch {batch})", plain),
        Row(size, params, f"focal train step incl. EMA (batch {batch})", ours, ours / plain, "plain FM"),
    ]


def render(rows: list[Row], device_name: str) -> str:
    lines = [
        f"Device: {device_name}; torch {torch.__version__}; threads {torch.get_num_threads()}",
        "",
        "| U-Net | params (M) | measurement | median ms | ratio |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        ratio = f"{r.ratio:.2f}× {r.ratio_to}" if r.ratio is not None else ""
        lines.append(f"| {r.size} {SIZES[r.size]} | {r.params_m:.1f} | {r.what} | {r.median_ms:.1f} | {ratio} |")
    return "\n".join(lines)


def plot(rows: list[Row], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = sorted({r.size for r in rows}, key=list(SIZES).index)
    fig, axes = plt.subplots(1, len(sizes), figsize=(6 * len(sizes), 3.6), squeeze=False)
    for ax, size in zip(axes[0], sizes, strict=True):
        sub = [r for r in rows if r.size == size]
        colors = ["C0" if "focal" in r.what else "C7" for r in sub]
        ax.barh([r.what for r in sub], [r.median_ms for r in sub], color=colors)
        ax.set_xscale("log")
        ax.set_xlabel("median ms (log)")
        ax.set_title(f"U-Net {SIZES[size]}")
        for i, r in enumerate(sub):
            ax.text(r.median_ms, i, f" {r.median_ms:.0f}", va="center", fontsize=8)
    save_png(fig, path, dpi=110)


def header(command: str) -> str:
    """The table file's title and the command that wrote it."""
    return (f"# Policy speed\n\nCommand: `{command}`. Observation: 9-d state + 39-d object poses at batch 1; "
            "focal horizon 12, diffusion horizon 16, ACT chunk 50 (one observation step); calls interleaved "
            "round-robin in one process, medians.\n\n")


def run(
    sizes: list[str], device: str, repeats: int, train_batch: dict[str, int], ddpm: bool, out_dir: Path,
    command: str = "lerobot-focal-bench speed",
) -> list[Row]:
    torch.manual_seed(0)
    if device.startswith("cuda"):
        device_name = torch.cuda.get_device_name(0)
    else:
        device_name = f"CPU {platform.processor() or platform.machine()} ({torch.get_num_threads()} threads)"
    rows: list[Row] = []
    for size in sizes:
        print(f"[speed] {size}: inference …", flush=True)
        rows += inference_rows(size, device, repeats, ddpm)
        print(f"[speed] {size}: training step …", flush=True)
        rows += training_rows(size, device, max(3, repeats // 2), train_batch[size])
    table = render(rows, device_name)
    print(table)
    out_dir.mkdir(parents=True, exist_ok=True)
    tag = "gpu" if device.startswith("cuda") else "cpu"
    (out_dir / f"policy_speed_{tag}.md").write_text(header(command) + table + "\n")
    (out_dir / f"policy_speed_{tag}.json").write_text(
        json.dumps({"device": device_name, "rows": [r.__dict__ for r in rows]}, indent=2)
    )
    plot(rows, out_dir / f"policy_speed_{tag}.png")
    print(f"[speed] wrote {out_dir}/policy_speed_{tag}.{{md,json,png}}")
    return rows
