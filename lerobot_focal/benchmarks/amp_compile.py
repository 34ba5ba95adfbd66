"""`lerobot-focal-bench amp-compile`: what LeRobot's AMP and compile switches change in focal's latency per chunk.

    lerobot-focal-bench amp-compile                                  # cpu_state-size network (U-Net 32/64/128)
    lerobot-focal-bench amp-compile --checkpoint outputs/train/<run>/checkpoints/last/pretrained_model
    lerobot-focal-bench amp-compile --down-dims 64 128 256 --repeats 50 --out docs/benchmarks

The rollout step that makes a new action chunk (`select_action` with an empty action queue, batch 1: observation
encoder + one U-Net evaluation) in four ways, the calls interleaved round-robin in one process so that load from
other processes hits all alike:

* ``eager``: as `lerobot-eval` and `lerobot-rollout` run it by default;
* ``amp``: inside ``torch.autocast(device_type=<device>)``, what ``--policy.use_amp=true`` makes `lerobot-eval`
  do (LeRobot 0.6.1; on a CPU autocast runs in bfloat16; `lerobot-rollout` autocasts only on CUDA);
* ``compile``: ``predict_action_chunk`` wrapped by ``torch.compile`` as ``lerobot-rollout --use_torch_compile=true``
  wraps it (LeRobot's own wrapper function when it is importable; backend ``--backend``, default inductor);
* ``compile+amp``: both.

Reported: median and p90 ms per chunk, the one-off time of the first compiled call (with and without autocast:
autocast is part of what the compiled code is specialised on), and the largest difference of the first action
from ``eager``'s with the same starting noise (normalised units, before the postprocessor). Latency does not depend on
the weights, so the default network is untrained; ``--checkpoint`` times a trained one, loaded as LeRobot loads it.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import platform
import statistics
import time
from pathlib import Path

import torch

from lerobot_focal.benchmarks.policy_speed import build_focal, time_ms
from lerobot_focal.console import doc_parser

VARIANTS = ("eager", "amp", "compile", "compile+amp")


def load_policy(checkpoint: Path | None, down_dims: tuple[int, ...], device: str):
    if checkpoint is None:
        return build_focal(down_dims, device).eval()
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class

    import lerobot_policy_focal  # noqa: F401  (registers focal, as every LeRobot CLI does)

    cfg = PreTrainedConfig.from_pretrained(checkpoint)
    cfg.device = device
    return get_policy_class(cfg.type).from_pretrained(checkpoint, config=cfg).to(device).eval()


def compiled_chunk(policy, backend: str, mode: str):
    """``policy.predict_action_chunk`` compiled the way ``lerobot-rollout --use_torch_compile=true`` does."""
    try:
        from lerobot.rollout.context import _wrap_predict_action_chunk_with_torch_compile as wrap
    except ImportError:  # another LeRobot layout: the same call
        return torch.compile(policy.predict_action_chunk, backend=backend, mode=mode)
    eager = policy.predict_action_chunk
    if not wrap(policy, backend=backend, mode=mode):
        raise RuntimeError("LeRobot could not configure torch.compile here (see its warning above)")
    compiled, policy.predict_action_chunk = policy.predict_action_chunk, eager  # keep the policy itself eager
    return compiled


def measure(policy, repeats: int, backend: str = "inductor", mode: str = "default") -> dict:
    cfg = policy.config
    device = str(cfg.device)
    batch = {k: torch.randn(1, *cfg.input_features[k].shape, device=device) for k in cfg.used_observation_keys}
    # The same starting noise in every call: the actions can be compared, and the compiled code sees one signature.
    noise = torch.randn(1, cfg.horizon, cfg.action_feature.shape[0], device=device)
    eager, compiled = policy.predict_action_chunk, compiled_chunk(policy, backend, mode)
    samples: dict[str, list[float]] = {name: [] for name in VARIANTS}

    def chunk_step(name: str) -> torch.Tensor:
        """The `select_action` call of a rollout step that makes a new chunk: one network evaluation."""
        policy.predict_action_chunk = compiled if name.startswith("compile") else eager
        policy.reset()
        ctx = torch.autocast(device_type=torch.device(device).type) if "amp" in name else contextlib.nullcontext()
        with torch.inference_mode(), ctx:
            t0 = time.perf_counter()
            action = policy.select_action(batch, noise=noise)
            samples[name].append((time.perf_counter() - t0) * 1e3)
        return action

    first_s = {}
    for name in ("compile", "compile+amp"):
        t0 = time.perf_counter()
        chunk_step(name)
        first_s[name] = time.perf_counter() - t0
    reference = chunk_step("eager").float()
    max_diff = {name: float((chunk_step(name).float() - reference).abs().max()) for name in VARIANTS}
    for values in samples.values():
        values.clear()
    medians = time_ms({name: (lambda name=name: chunk_step(name)) for name in VARIANTS}, device, repeats, warmup=1)
    policy.predict_action_chunk = eager
    rows = {}
    for name in VARIANTS:
        timed = sorted(samples[name][-repeats:])
        rows[name] = {"median_ms": round(statistics.median(timed), 2),
                      "p90_ms": round(timed[int(0.9 * (len(timed) - 1))], 2),
                      "speedup": round(medians["eager"] / medians[name], 2),
                      "max_abs_action_diff": round(max_diff[name], 5)}
    return {
        "variants": rows,
        "first_compiled_call_s": {k: round(v, 1) for k, v in first_s.items()},
        "params_m": round(sum(p.numel() for p in policy.model.parameters()) / 1e6, 2),
        "down_dims": list(cfg.down_dims), "inputs": list(cfg.used_observation_keys), "device": device,
        "backend": backend, "mode": mode, "repeats": repeats, "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(), "machine": platform.processor() or platform.machine(),
    }


def write_report(result: dict, out: Path, command: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "amp_compile.json").write_text(json.dumps({**result, "command": command}, indent=2) + "\n")
    lines = [
        f"# focal: AMP and compile, latency per chunk ({result['device']})", "",
        f"`{command}`", "",
        f"U-Net {'/'.join(map(str, result['down_dims']))} ({result['params_m']} M parameters), inputs "
        f"{', '.join(result['inputs'])}, batch 1; torch {result['torch']}, {result['torch_threads']} threads; "
        f"{result['repeats']} interleaved calls each. Compile backend `{result['backend']}`, mode `{result['mode']}`.",
        "", "| variant | median ms | p90 ms | × eager | max abs Δ action vs eager |", "|---|---|---|---|---|",
    ]
    for name, row in result["variants"].items():
        lines.append(f"| {name} | {row['median_ms']} | {row['p90_ms']} | {row['speedup']} | "
                     f"{row['max_abs_action_diff']} |")
    first = result["first_compiled_call_s"]
    lines += ["", f"First compiled call (compilation): {first['compile']} s; with autocast: {first['compile+amp']} s.",
              ""]
    (out / "amp_compile.md").write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "lerobot-focal-bench amp-compile")
    parser.add_argument("--checkpoint", type=Path, default=None, help="a pretrained_model folder (default: untrained)")
    parser.add_argument("--down-dims", type=int, nargs="+", default=[32, 64, 128])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--backend", default="inductor")
    parser.add_argument("--mode", default="default")
    parser.add_argument("--out", type=Path, default=Path("outputs/amp_compile"))
    args: argparse.Namespace = parser.parse_args(argv)
    policy = load_policy(args.checkpoint, tuple(args.down_dims), args.device)
    result = measure(policy, args.repeats, args.backend, args.mode)
    command = "lerobot-focal-bench amp-compile " + " ".join(argv if argv is not None else __import__("sys").argv[1:])
    write_report(result, args.out, command.strip())
    print((args.out / "amp_compile.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
