"""The benchmark grid: (task x method x seed) runs through LeRobot's own `lerobot-train`, the paper's protocol.

Modules, one job each:

* ``presets``  — the CPU and paper scales (steps, evaluation cadence, network size, observations);
* ``methods``  — every method of the comparison as `lerobot-train` arguments (focal, its ablations, diffusion,
  DP w. FCO);
* ``datasets`` — expert demonstrations per task (training and held-out), made once and shared by all runs;
* ``run``      — one run: train with periodic evaluation, then the checkpoint metrics; returns one result record;
* ``processes``— the runs' child processes (collection, lerobot-train, lerobot-eval), stoppable as one;
* ``metrics``  — top-5 success, ATV, TS score, open-loop compounding error (pure functions);
* ``results``  — the append-only results file that makes an interrupted grid resumable;
* ``executors``— sequential in-process, or Ray tasks on a local or remote cluster;
* ``report``   — Markdown table in the paper's layout, goals, PNG plots;
* ``variant_eval`` — a grid's final focal checkpoints again, with another inference setting.
"""
