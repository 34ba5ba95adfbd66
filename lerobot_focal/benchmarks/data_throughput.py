"""Data time vs update time per batch in LeRobot's own ``lerobot-train``: stock reader vs the fast reader.

    python -m lerobot_focal.benchmarks.data_throughput                       # synthetic (512, 3) point clouds
    python -m lerobot_focal.benchmarks.data_throughput --root data/mw_pc --repo_id local/mw_pc --repeats 2

Each run is a real ``lerobot-train`` subprocess (``configs/focal_cpu.json``, batch 64, ``--num_workers=0``,
no checkpoint) on the same dataset; the two modes alternate (stock, fast, stock, fast, ...) so that load from
other processes hits both alike. ``data_s`` and ``updt_s`` are parsed from LeRobot's own log lines (each the
mean over ``--log_freq`` steps); the first log window of every run is dropped (warm-up) and the medians of the
rest are reported, with data_s / updt_s as the figure of merit (goal <= 0.25).

The fast mode sets ``LEROBOT_FOCAL_FAST_READER=1``. If the installed plugin does not yet call
``install_from_env()`` at import, the fast runs use ``python -m lerobot_focal.datasets.fast_loading.fast_reader``
instead, which installs the reader and then calls LeRobot's ``lerobot_train.main`` unchanged; the log must show the
reader's ``fast reader: ... cached`` line or the run is reported as not accelerated.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lerobot_focal.console import console_script, doc_parser
from lerobot_focal.figures import save_png
from lerobot_focal.presets import preset_path

LOG_RE = re.compile(r"updt_s:([0-9.]+) data_s:([0-9.]+)")
CACHED_RE = re.compile(r"fast reader: (\d+) columns cached in memory \(([0-9.]+) MB\)")
REPO = Path(__file__).resolve().parents[2]


def _plugin_wires_env() -> bool:
    """Whether importing the plugin (as every lerobot-* CLI does) installs the reader when the env var is set."""
    code = ("import lerobot_policy_focal, sys; from lerobot_focal.datasets.fast_loading import fast_reader as f; "
            "sys.exit(0 if f.is_installed() else 3)")
    env = {**os.environ, "LEROBOT_FOCAL_FAST_READER": "1"}
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True).returncode == 0


def _command(mode: str, wired: bool) -> tuple[list[str], dict[str, str]]:
    env = {k: v for k, v in os.environ.items() if k != "LEROBOT_FOCAL_FAST_READER"}
    env.update(HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1", WANDB_MODE="disabled")
    lerobot_train = console_script("lerobot-train")
    if mode == "stock":
        return [lerobot_train], env
    env["LEROBOT_FOCAL_FAST_READER"] = "1"
    if wired:
        return [lerobot_train], env
    return [sys.executable, "-m", "lerobot_focal.datasets.fast_loading.fast_reader"], env


def run_once(mode: str, wired: bool, args: argparse.Namespace, out_dir: Path) -> dict:
    cmd, env = _command(mode, wired)
    cmd = cmd + [
        f"--config_path={args.config}",
        f"--dataset.repo_id={args.repo_id}",
        f"--dataset.root={args.root}",
        f"--batch_size={args.batch_size}",
        "--num_workers=0",
        f"--steps={args.steps}",
        f"--log_freq={args.log_freq}",
        "--save_checkpoint=false",
        f"--output_dir={out_dir}",
    ]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    log = proc.stdout + proc.stderr
    if proc.returncode != 0:
        raise RuntimeError(f"{mode} run failed ({proc.returncode}):\n{log[-4000:]}")
    windows = [(float(u), float(d)) for u, d in LOG_RE.findall(log)]
    cached = CACHED_RE.search(log)
    return {
        "mode": mode,
        "command": " ".join(cmd),
        "wall_s": round(wall, 1),
        "windows": [{"update_s": u, "data_s": d} for u, d in windows],
        "accelerated": cached is not None,
        "cached_mb": float(cached.group(2)) if cached else None,
    }


def _summary(runs: list[dict]) -> dict:
    windows = [w for r in runs for w in r["windows"][1:]] or [w for r in runs for w in r["windows"]]
    data = statistics.median(w["data_s"] for w in windows)
    upd = statistics.median(w["update_s"] for w in windows)
    return {"data_s": data, "update_s": upd, "data_over_update": data / upd if upd else float("nan"),
            "windows": len(windows), "accelerated": all(r["accelerated"] for r in runs)}


def item_timings(root: Path, repo_id: str, config: Path, n: int = 64) -> dict:
    """Per-item ``LeRobotDataset.__getitem__`` cost, stock vs fast, in this process, with the delta timestamps the
    config's policy asks for (median over `n` random items each, interleaved)."""
    import random

    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

    import lerobot_focal  # noqa: F401  (registers `focal`)
    from lerobot_focal.datasets.fast_loading import fast_reader

    policy_cfg = json.loads(Path(config).read_text())["policy"]
    cfg = PreTrainedConfig.get_choice_class(policy_cfg.pop("type"))(**{k: v for k, v in policy_cfg.items()})
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    deltas = resolve_delta_timestamps(cfg, meta)
    stock = LeRobotDataset(repo_id, root=root, delta_timestamps=deltas)
    with fast_reader.enabled():
        t0 = time.perf_counter()
        fast = LeRobotDataset(repo_id, root=root, delta_timestamps=deltas)
        open_fast = time.perf_counter() - t0
        order = random.Random(0).sample(range(len(stock)), min(n, len(stock)))
        times: dict[str, list[float]] = {"stock": [], "fast": []}
        for i in order:
            for name, ds in (("stock", stock), ("fast", fast)):
                t0 = time.perf_counter()
                ds[i]
                times[name].append(time.perf_counter() - t0)
    med = {k: statistics.median(v) for k, v in times.items()}
    return {"stock_ms": med["stock"] * 1e3, "fast_ms": med["fast"] * 1e3, "ratio": med["stock"] / med["fast"],
            "fast_open_s": open_fast, "cached_mb": fast.reader._focal_cache.nbytes / 2**20, "items": len(order)}


def _plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    modes = ["stock", "fast"]
    data = [result["summary"][m]["data_s"] for m in modes]
    upd = [result["summary"][m]["update_s"] for m in modes]
    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    ax.barh(modes, data, color="tab:red", label="data_s (read + collate + preprocess)")
    ax.barh(modes, upd, left=data, color="tab:blue", label="updt_s (forward/backward/step)")
    for i, (d, u) in enumerate(zip(data, upd, strict=True)):
        ax.text(d + u, i, f"  data/update = {d / u:.3f}", va="center", fontsize=8)
    ax.set_xlabel("seconds per batch (median over log windows)")
    ax.set_title(f"lerobot-train, focal CPU preset, batch {result['batch_size']}: {result['dataset']}", fontsize=8)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_xlim(0, max(d + u for d, u in zip(data, upd, strict=True)) * 1.45)
    save_png(fig, path, dpi=120)


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "lerobot-focal-bench data")
    parser.add_argument("--root", type=Path, default=None,
                        help="LeRobotDataset root (default: write a synthetic 12x40-frame (512,3) point-cloud dataset)")
    parser.add_argument("--repo_id", default="local/focal_synthetic")
    parser.add_argument("--config", type=Path, default=preset_path("cpu"))
    parser.add_argument("--batch_size", type=int, default=64)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--log_freq", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1, help="runs per mode, alternating stock/fast")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "benchmarks")
    parser.add_argument("--name", default="data_throughput", help="basename of the JSON and PNG written to --out")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="focal_data_bench_") as tmp:
        tmp = Path(tmp)
        if args.root is None:
            from lerobot_focal.datasets.making.synthetic import SyntheticSpec, write_synthetic_dataset

            args.root = tmp / "dataset"
            write_synthetic_dataset(args.root, SyntheticSpec(num_points=512), repo_id=args.repo_id)
        items = item_timings(args.root, args.repo_id, args.config)
        print(f"per item: stock {items['stock_ms']:.2f} ms, fast {items['fast_ms']:.3f} ms "
              f"({items['ratio']:.0f}x); cache {items['cached_mb']:.1f} MB built in {items['fast_open_s']:.2f} s "
              "(dataset open included)", flush=True)
        wired = _plugin_wires_env()
        runs: list[dict] = []
        for rep in range(args.repeats):
            for mode in ("stock", "fast"):
                run = run_once(mode, wired, args, tmp / f"out_{mode}_{rep}")
                runs.append(run)
                print(f"[{mode} #{rep}] {len(run['windows'])} log windows, wall {run['wall_s']} s, "
                      f"accelerated={run['accelerated']}", flush=True)

    info = json.loads((Path(args.root) / "meta" / "info.json").read_text())
    result = {
        "dataset": f"{args.repo_id} ({info['total_episodes']} episodes, {info['total_frames']} frames)",
        "features": {k: v["shape"] for k, v in info["features"].items() if k.startswith(("observation", "action"))},
        "config": str(args.config),
        "batch_size": args.batch_size,
        "steps": args.steps,
        "log_freq": args.log_freq,
        "plugin_wires_env": wired,
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                    "load_avg_at_end": os.getloadavg()},
        "per_item": items,
        "runs": runs,
        "summary": {m: _summary([r for r in runs if r["mode"] == m]) for m in ("stock", "fast")},
    }
    s, f = result["summary"]["stock"], result["summary"]["fast"]
    result["data_speedup"] = s["data_s"] / f["data_s"] if f["data_s"] else float("inf")

    print(f"\n{result['dataset']}, batch {args.batch_size}, {args.config.name}")
    print(f"{'reader':<8} {'data_s/batch':>13} {'updt_s/batch':>13} {'data/update':>12}")
    for m, v in (("stock", s), ("fast", f)):
        print(f"{m:<8} {v['data_s']:>13.3f} {v['update_s']:>13.3f} {v['data_over_update']:>12.3f}")
    print(f"data time: {result['data_speedup']:.1f}x less with the fast reader; "
          f"goal data/update <= 0.25: {'met' if f['data_over_update'] <= 0.25 else 'NOT met'}")
    if not f["accelerated"]:
        print("WARNING: the fast runs did not log the cache line; they ran on the stock reader")

    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{args.name}.json").write_text(json.dumps(result, indent=2))
    _plot(result, args.out / f"{args.name}.png")
    print(f"wrote {args.out / (args.name + '.json')} and .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
