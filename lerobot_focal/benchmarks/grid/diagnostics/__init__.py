"""Tools that study a grid's runs after the fact, each a `lerobot-focal-bench` subcommand: ``lr-sweep`` (one
grid invocation per method and learning rate, and the rate each method gets), ``expert-gap`` (each final
checkpoint against MetaWorld's scripted expert, state by state), ``tau-profile`` (where along the flow a focal
checkpoint's one-step map is wrong), ``variant-eval`` (the final checkpoints with another inference setting).

They read a finished grid through its ``grid.json`` and ``results.jsonl`` (``..specs``, ``..results``) and
write their own files beside its report; the harness never imports them.
"""
