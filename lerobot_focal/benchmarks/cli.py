"""`lerobot-focal-bench`: the project's benchmarks behind one command.

    lerobot-focal-bench speed [--sizes grid cpu paper] [--device cpu|cuda] [--repeats 7] [--out docs/benchmarks]
    lerobot-focal-bench data  [--root DATASET] ...   (stock vs fast dataset reader inside lerobot-train)
    lerobot-focal-bench grid  --preset cpu|paper --tasks ... --methods ... --out DIR   (the paper's protocol)
    lerobot-focal-bench report --out DIR                (re-render a grid's report.md and plots)
    lerobot-focal-bench rescore --out DIR --work WORK   (a grid's final checkpoints on 15 x 20 fresh episodes:
                                                        top-5 of blocks)
    lerobot-focal-bench lr-sweep --task T --runs METHOD=LR,LR ... --out DIR  (one grid per method and rate)
    lerobot-focal-bench expert-gap --out DIR            (a grid's final checkpoints against the scripted expert)
    lerobot-focal-bench tau-profile --out DIR           (where along the flow focal's one-step map is wrong)
    lerobot-focal-bench variant-eval --variant V --out DIR  (a grid's final checkpoints, another inference setting)
    lerobot-focal-bench checkpoint-eval --out DIR       (a run's kept late checkpoints on the same fresh episodes)
    lerobot-focal-bench train-step [--compile]          (what makes a CPU training step cheaper)
    lerobot-focal-bench camera-step [--clouds DATASET]  (a point-cloud / image training step against a low-dim one:
                                                        bf16 autocast, channels-last, fewer points; loss curves)
    lerobot-focal-bench act-precision --data DATASET   (the grid's ACT in float32 vs bf16 autocast: step time,
                                                        loss curves from the same weights)
    lerobot-focal-bench allocator [--inputs pointcloud state]  (glibc malloc settings vs the CPU training step)
    lerobot-focal-bench eval-profile --checkpoint CKPT  (where one lerobot-eval's time goes)
    lerobot-focal-bench cloud-content [--tasks ...]     (what a MetaWorld cloud's points fall on: table, arm, objects)
    lerobot-focal-bench execution-cost [--tasks ...]    (the scripted expert in open-loop chunks, with action noise)
    lerobot-focal-bench amp-compile [--checkpoint CKPT] (latency per chunk: --policy.use_amp, --use_torch_compile)
    lerobot-focal-bench rollout [--width 848 --height 480 --fps 30 --duration 120]
                                                        (lerobot-rollout on the UR-10e twin: stage latencies)
    lerobot-focal-bench inference-modes [--delays 0 1 2 3] (focal with / without RTC at simulated delays:
                                                        MetaWorld and the twin)
"""

from __future__ import annotations

from pathlib import Path

from lerobot_focal.console import doc_parser

# Subcommands that parse their own arguments: command -> module with main(argv).
_DELEGATED = {
    "data": "lerobot_focal.benchmarks.data_throughput",
    "grid": "lerobot_focal.benchmarks.grid.driver",
    "report": "lerobot_focal.benchmarks.grid.report",
    "rescore": "lerobot_focal.benchmarks.grid.rescore",
    "lr-sweep": "lerobot_focal.benchmarks.grid.diagnostics.lr_sweep",
    "expert-gap": "lerobot_focal.benchmarks.grid.diagnostics.expert_gap",
    "tau-profile": "lerobot_focal.benchmarks.grid.diagnostics.tau_profile",
    "variant-eval": "lerobot_focal.benchmarks.grid.diagnostics.variant_eval",
    "checkpoint-eval": "lerobot_focal.benchmarks.grid.diagnostics.checkpoint_eval",
    "execution-cost": "lerobot_focal.benchmarks.execution_cost",
    "eval-profile": "lerobot_focal.benchmarks.eval_profile",
    "rollout": "lerobot_focal.benchmarks.rollout_latency",
    "cloud-content": "lerobot_focal.benchmarks.cloud_content",
    "allocator": "lerobot_focal.benchmarks.allocator",
    "train-step": "lerobot_focal.benchmarks.train_step",
    "amp-compile": "lerobot_focal.benchmarks.amp_compile",
    "camera-step": "lerobot_focal.benchmarks.camera_step",
    "act-precision": "lerobot_focal.benchmarks.act_precision",
    "inference-modes": "lerobot_focal.benchmarks.inference_modes",
}


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "lerobot-focal-bench")
    sub = parser.add_subparsers(dest="command", required=True)
    speed = sub.add_parser("speed",
                           help="inference latency and train-step cost: focal vs bare U-Net vs diffusion vs ACT")
    speed.add_argument("--sizes", nargs="+", choices=["grid", "cpu", "paper"], default=["cpu", "paper"],
                       help="U-Net sizes: grid 32/64/128 (the CPU grid presets), cpu 64/128/256, paper 512/1024/2048")
    speed.add_argument("--device", default="cuda" if _cuda() else "cpu")
    speed.add_argument("--repeats", type=int, default=7)
    speed.add_argument("--cpu-train-batch", type=int, default=64,
                       help="train batch for the grid- and CPU-preset networks")
    speed.add_argument("--paper-train-batch", type=int, default=None,
                       help="train batch for the paper-size network (default: 128 on GPU, 16 on CPU)")
    speed.add_argument("--no-ddpm", action="store_true", help="skip DDPM 100 (≈ 30 s per call at paper size on CPU)")
    speed.add_argument("--threads", type=int, default=None,
                       help="torch intra-op threads (default: torch's). On a shared machine 1 avoids oversubscription")
    speed.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    sub.add_parser("data", add_help=False,
                   help="data vs update time per batch in lerobot-train: stock reader vs the fast reader "
                        "(arguments: see `lerobot-focal-bench data --help`)")
    sub.add_parser("grid", add_help=False, help="(task x method x seed) through lerobot-train, the paper's protocol "
                                                 "(see `lerobot-focal-bench grid --help`)")
    sub.add_parser("report", add_help=False, help="render a grid's report (see `lerobot-focal-bench report --help`)")
    sub.add_parser("rescore", add_help=False,
                   help="score a finished grid's final checkpoints the paper's way: top-5 of 15 blocks of fresh "
                        "episodes (see `lerobot-focal-bench rescore --help`)")
    sub.add_parser("lr-sweep", add_help=False, help="one grid invocation per method and learning rate on one task "
                                                     "and seed, and the rate each method gets")
    sub.add_parser("expert-gap", add_help=False, help="a grid's final checkpoints against MetaWorld's scripted "
                                                       "expert, state by state")
    sub.add_parser("tau-profile", add_help=False, help="where along the flow a grid's focal checkpoints' one-step "
                                                        "map is still wrong")
    sub.add_parser("variant-eval", add_help=False, help="a grid's final checkpoints with another inference setting "
                                                         "on the same fresh episodes")
    sub.add_parser("checkpoint-eval", add_help=False, help="a run's kept late checkpoints on the episodes of its final "
                                                            "evaluation: do they differ, or only the draws?")
    sub.add_parser("train-step", add_help=False, help="CPU training-step variants: optimizer, threads, batch, compile")
    sub.add_parser("camera-step", add_help=False, help="a point-cloud or image training step against a low-dim one, "
                                                        "and cheaper variants with their loss curves")
    sub.add_parser("act-precision", add_help=False, help="the grid's ACT in float32 and under bf16 autocast: step "
                                                          "time and loss curves from the same weights")
    sub.add_parser("allocator", add_help=False, help="glibc malloc settings against focal's CPU training step")
    sub.add_parser("cloud-content", add_help=False, help="share of a MetaWorld cloud's points on the table, the arm "
                                                         "and the task's objects, env crop vs the previous box")
    sub.add_parser("execution-cost", add_help=False, help="what chunked open-loop execution and action noise cost "
                                                          "MetaWorld's scripted expert, per development task")
    sub.add_parser("eval-profile", add_help=False, help="where one lerobot-eval's time goes (cProfile, grouped)")
    sub.add_parser("amp-compile", add_help=False, help="latency per chunk with LeRobot's AMP (autocast) and "
                                                       "lerobot-rollout's torch.compile switch, each and both")
    sub.add_parser("rollout", add_help=False, help="lerobot-rollout on the UR-10e twin at 848x480: per-stage latency "
                                                   "and loop rate (see `lerobot-focal-bench rollout --help`)")
    sub.add_parser("inference-modes", add_help=False, help="focal with and without real-time chunking (RTC) at "
                                                           "simulated inference delays, on MetaWorld and the twin")
    if argv is None:
        import sys

        argv = sys.argv[1:]
    if argv[:1] and argv[0] in _DELEGATED:  # commands with their own parser and --help
        import importlib

        return importlib.import_module(_DELEGATED[argv[0]]).main(argv[1:])
    args = parser.parse_args(argv)

    if args.command == "speed":
        import torch

        from lerobot_focal.benchmarks.policy_speed import run

        if args.threads:
            torch.set_num_threads(args.threads)

        paper_batch = args.paper_train_batch or (128 if args.device.startswith("cuda") else 16)
        batches = {"grid": args.cpu_train_batch, "cpu": args.cpu_train_batch, "paper": paper_batch}
        run(args.sizes, args.device, args.repeats, batches, not args.no_ddpm, args.out,
            command=" ".join(["lerobot-focal-bench", *argv]))
    return 0


def _cuda() -> bool:
    import torch

    return torch.cuda.is_available()


if __name__ == "__main__":
    raise SystemExit(main())
