"""The benchmark grid: (task x method x seed) runs through LeRobot's own `lerobot-train`, the paper's protocol.

Modules, one job each, in the order a run meets them:

* ``grid_presets`` — the CPU and paper scales (steps, evaluation cadence, network size, observations, schedule);
* ``methods``  — every method of the comparison as `lerobot-train` arguments, each describing itself to the report;
* ``seeds``    — every reset-seed range a run uses, by purpose, and the check that none overlap;
* ``demos``    — expert demonstrations per task (training and held-out), made once and shared by all runs;
* ``specs``    — the runs of a grid (``RunSpec``), from the command line or from a results folder's ``grid.json``;
* ``run``      — one run: train with periodic evaluation, then the checkpoint metrics; returns a ``RunRecord``;
* ``resume``   — where an interrupted run continues from (LeRobot's checkpoints and ``--resume``);
* ``processes``— the runs' child processes (collection, lerobot-train, lerobot-eval), stoppable as one;
* ``analyze``  — the final checkpoint's held-out open-loop metrics, latency and NFE (a child process);
* ``metrics``  — top-5 success, ATV, TS score, open-loop compounding error, paired intervals (pure functions);
* ``results``  — ``RunRecord`` and the append-only results file that makes an interrupted grid resumable;
* ``executors``— runs at a time on this machine, or Ray tasks on a local or remote cluster;
* ``driver``   — `lerobot-focal-bench grid`: the command line, ``grid.json``, progress;
* ``rescore``  — a finished grid's final checkpoints the paper's way (top-5 of 15 blocks of fresh episodes);
* ``revisit``  — the command line and loop shared by the tools that revisit a finished grid's runs;
* ``report``   — Markdown tables in the paper's layout, goals, PNG plots, ``summary.json``;
* ``diagnostics/`` — lr-sweep, expert-gap, tau-profile, variant-eval: `lerobot-focal-bench` subcommands that study
  a grid's runs after the fact.
"""
