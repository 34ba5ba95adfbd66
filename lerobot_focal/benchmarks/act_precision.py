"""`lerobot-focal-bench act-precision`: would bf16 autocast make the grid's ACT cheaper without changing it?

    lerobot-focal-bench act-precision --data outputs/bench/data/cpu_fair/disassemble/train-demos1000 \
        --repo-id local/disassemble_train_demos1000 --out docs/benchmarks

ACT is the grid's costliest method on a CPU (its 50-step chunk runs through the transformer in every step). This
trains the grid's ACT (LeRobot's `ACTPolicy` with the grid's chunk, width and learning rate, `methods._act_inputs`)
twice from the same weights, in float32 and under CPU bf16 autocast, on the same batches of a grid dataset and
the same noise (dropout, the VAE's sample) at every step, and reports the step time of each and the two loss
curves. A cheaper setting is adopted only where the curves agree as `camera-step`'s did (within a fraction of a
percent); otherwise the grid keeps ACT in float32, its authors' precision.

``--threads N`` times the steps on N torch threads (default 1, as a grid run beside another gets). ``--dropout-cost``
adds a third row, float32 with ACT's dropout set to 0 (the same weights otherwise): a timing row only, as it is
another training, which says how much of ACT's CPU step is drawing dropout masks.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from lerobot_focal.console import doc_parser

#: What ACT reads of a grid dataset (the agent state and, where recorded, the object poses) and its targets.
OBSERVATIONS = ("observation.state", "observation.environment_state")
TARGETS = ("action", "action_is_pad")
#: Largest relative difference of the two losses (mean of the last fifth) at which bf16 counts as the same training;
#: camera-step's bf16 variants of focal differ by 0.1-0.3 %.
AGREEMENT = 0.01


#: Training steps per variant unless --steps says otherwise.
DEFAULT_STEPS = 300
#: The timing-only row of ``--dropout-cost``: ACT without its dropout, which trains another ACT.
NO_DROPOUT = "float32, dropout 0"


def _policy_and_batches(root: Path, repo_id: str, preset_name: str, batch: int):
    from lerobot.configs.types import FeatureType
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.utils.feature_utils import dataset_to_policy_features

    from lerobot_focal.benchmarks.grid.grid_presets import PRESETS
    from lerobot_focal.benchmarks.grid.methods import ACT_CHUNK, act_config

    preset = PRESETS[preset_name]
    probe = LeRobotDataset(repo_id, root=root)
    features = dataset_to_policy_features(probe.meta.features)
    config = act_config(preset, {k: f for k, f in features.items() if k in OBSERVATIONS},
                        {k: f for k, f in features.items() if f.type is FeatureType.ACTION},
                        device="cpu", optimizer_lr=preset.lr_for("act"))
    dataset = LeRobotDataset(repo_id, root=root,
                             delta_timestamps={"action": [i / probe.meta.fps for i in range(ACT_CHUNK)]})
    pre, _ = make_pre_post_processors(config, dataset_stats=dataset.meta.stats)
    # The demos are small (2000 frames): read once, then batches from memory, so the steps time the model only.
    frames = [dataset[i] for i in range(len(dataset))]
    data = {k: torch.stack([f[k] for f in frames]) for k in (*config.input_features, *TARGETS)}
    g = torch.Generator().manual_seed(0)

    def batches():
        while True:
            for idx in torch.randperm(len(frames), generator=g).split(batch):
                if len(idx) == batch:
                    yield pre({k: v[idx] for k, v in data.items()})

    torch.manual_seed(0)
    return ACTPolicy(config), config, batches()


def _without_dropout(policy, config):
    """The same ACT (same weights) built with ``dropout=0``: LeRobot's ACT reads its dropout from the config."""
    from lerobot.policies.act.modeling_act import ACTPolicy

    twin = ACTPolicy(dataclasses.replace(config, dropout=0.0))
    twin.load_state_dict(policy.state_dict())
    return twin


def measure(root: Path, repo_id: str, preset_name: str, steps: int, batch: int, threads: int = 1,
            dropout_cost: bool = False) -> dict:
    torch.set_num_threads(threads)
    policy, config, batches = _policy_and_batches(root, repo_id, preset_name, batch)
    runs = {"float32": (policy, False), "bf16 autocast": (copy.deepcopy(policy), True)}
    if dropout_cost:
        runs[NO_DROPOUT] = (_without_dropout(policy, config), False)
    preset = config.get_optimizer_preset()  # what lerobot-train builds for ACT: AdamW, clip at grad_clip_norm
    optimizers = {name: preset.build(p.parameters()) for name, (p, _) in runs.items()}
    losses: dict[str, list[float]] = {name: [] for name in runs}
    times: dict[str, list[float]] = {name: [] for name in runs}
    for step in range(steps):
        batch_ = next(batches)
        for name, (p, amp) in runs.items():
            torch.manual_seed(step)  # the same dropout masks and VAE samples for both
            start = time.perf_counter()
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=amp):
                loss, _ = p.forward(batch_)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(p.parameters(), preset.grad_clip_norm)
            optimizers[name].step()
            optimizers[name].zero_grad()
            times[name].append(time.perf_counter() - start)
            losses[name].append(float(loss.detach()))
        if step % 50 == 0:
            print(f"[act-precision] step {step}: " + ", ".join(f"{n} {v[-1]:.3f}" for n, v in losses.items()),
                  flush=True)
    tail = max(1, steps // 5)
    rows = {name: {"ms_per_step": 1000 * statistics.median(times[name][2:]),
                   "loss_last_fifth": float(np.mean(losses[name][-tail:]))} for name in runs}
    base = rows["float32"]
    for row in rows.values():
        row["speedup"] = base["ms_per_step"] / row["ms_per_step"]
        row["loss_difference"] = row["loss_last_fifth"] / base["loss_last_fifth"] - 1
    return {"data": str(root), "preset": preset_name, "steps": steps, "batch": batch, "chunk": config.chunk_size,
            "width": [config.dim_model, config.dim_feedforward], "lr": config.optimizer_lr, "threads": threads,
            "rows": rows, "loss_curves": losses}


def render(result: dict) -> str:
    threads = result.get("threads", 1)
    times = "three times" if NO_DROPOUT in result["rows"] else "twice"
    md = [f"# ACT in float32 and under bf16 autocast on a CPU (the grid's ACT, batch {result['batch']}, "
          f"{'one thread' if threads == 1 else f'{threads} threads'})",
          "", f"`lerobot-focal-bench act-precision --data {result['data']}{_options(result)}`: LeRobot's ACT with the "
          f"{result['preset']} "
          f"grid's settings (chunk {result['chunk']}, width {result['width'][0]}/{result['width'][1]}, lr "
          f"{result['lr']:g}), trained {result['steps']} steps {times} from the same weights on the same batches and "
          "noise. Step time: median over the steps; loss: mean of the last fifth ([curves](act_precision.png)).", "",
          "| precision | ms / step | speed-up | loss | loss vs float32 |", "|---|---|---|---|---|"]
    md += [f"| {name} | {r['ms_per_step']:.0f} | {r['speedup']:.2f}× | {r['loss_last_fifth']:.4f} | "
           f"{r['loss_difference'] * 100:+.1f} % |" for name, r in result["rows"].items()]
    if NO_DROPOUT in result["rows"]:
        share = 1 - 1 / result["rows"][NO_DROPOUT]["speedup"]
        md += ["", f"Without dropout (a timing row: another training, so its loss is not a candidate) a step takes "
               f"{share:.0%} less: that share of ACT's float32 step is its dropout."]
    diff = result["rows"]["bf16 autocast"]["loss_difference"]
    md += ["", f"The curves agree (within {AGREEMENT:.0%}): bf16 autocast would train the same ACT, cheaper."
           if abs(diff) <= AGREEMENT else
           f"The curves differ by {diff:+.1%} (more than {AGREEMENT:.0%}): bf16 autocast trains another ACT, so the "
           "grid keeps ACT in float32, its authors' precision, and pays its step time."]
    return "\n".join(md) + "\n"


def _options(result: dict) -> str:
    """The command-line options that made ``result`` beyond --data (the defaults left out)."""
    options = [f"--steps {result['steps']}"] if result["steps"] != DEFAULT_STEPS else []
    options += [f"--threads {result['threads']}"] if result.get("threads", 1) != 1 else []
    options += ["--dropout-cost"] if NO_DROPOUT in result["rows"] else []
    return "".join(f" {o}" for o in options)


def _plot(path: Path, curves: dict[str, list[float]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lerobot_focal.figures import save_png

    fig, ax = plt.subplots(figsize=(5, 3.2))
    for (name, values), style in zip(curves.items(), ("-", "--", ":"), strict=False):
        window = max(1, len(values) // 20)
        smooth = np.convolve(values, np.ones(window) / window, mode="valid")
        ax.plot(np.arange(len(smooth)) + window, smooth, ls=style, label=name)
    ax.set_yscale("log")
    ax.set_xlabel("training step")
    ax.set_ylabel("ACT loss (running mean)")
    ax.legend()
    save_png(fig, path)


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "lerobot-focal-bench act-precision")
    parser.add_argument("--data", type=Path, required=True, help="a grid dataset (state + object poses) root")
    parser.add_argument("--repo-id", default="local/demos", help="its repo id (any name for a local dataset)")
    parser.add_argument("--preset", default="cpu_fair", help="the grid preset whose ACT settings to use")
    parser.add_argument("--steps", type=int, default=DEFAULT_STEPS)
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--threads", type=int, default=1, help="torch threads for the steps (default 1)")
    parser.add_argument("--dropout-cost", action="store_true",
                        help="also time float32 ACT with dropout 0 (same weights): dropout's share of a step")
    parser.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    args: argparse.Namespace = parser.parse_args(argv)
    if args.threads < 1:
        parser.error(f"--threads {args.threads}: give 1 or more")
    result = measure(args.data, args.repo_id, args.preset, args.steps, args.batch, args.threads, args.dropout_cost)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "act_precision.json").write_text(json.dumps(result, indent=1))
    _plot(args.out / "act_precision.png", result["loss_curves"])
    (args.out / "act_precision.md").write_text(render(result))
    print(render(result))
    return 0
