"""`lerobot-train` with a per-rank probe, for tests/policy/test_accelerate.py (run via `accelerate launch`).

LeRobot's own training entry point runs unchanged; the probe only wraps two functions from the outside:

* `FocalPolicy.update` (called by lerobot-train on the unwrapped policy after every optimizer step): after
  the EMA update, record the EMA step counter and a SHA-256 of the EMA and online weights;
* `modeling_focal.consistency_loss`: record a SHA-256 of the noise M_0, the times (τ, r) and the expert
  macro-trajectories M_1 each rank trains on, and the loss.

Each rank appends JSON lines to `$FOCAL_PROBE_DIR/rank<RANK>.jsonl`. Without FOCAL_PROBE_DIR this is just
lerobot-train.

Exit workaround (torch 2.11 + gloo, not a policy issue): when `train()` returns, freeing the DDP wrapper destroys
its Reducer, which drops the last reference to the gloo process group while holding the GIL; ~ProcessGroupGloo
then joins its worker thread, which may be waiting for the GIL to free a finished all-reduce's tensors: the
rank hangs forever after "End of training" (seen once in six 2-process runs here; gdb:
ProcessGroupGloo::~ProcessGroupGloo -> thread::join vs. AsyncAllreduceWork::~AsyncAllreduceWork -> take_gil).
So, in a multi-process run, the probe leaves each rank with os._exit right after LeRobot's own
`accelerator.end_training()`: everything
(checkpoints, logs, the process group's shutdown) is done by then.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import torch


def sha(tensors) -> str:
    h = hashlib.sha256()
    for t in tensors:
        h.update(t.detach().to("cpu").contiguous().view(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def install(probe_dir: Path) -> None:
    from lerobot_focal.policy import modeling_focal

    rank = int(os.environ.get("RANK", "0"))
    probe_dir.mkdir(parents=True, exist_ok=True)
    out = probe_dir / f"rank{rank}.jsonl"

    def write(record: dict) -> None:
        with out.open("a") as f:
            f.write(json.dumps({"rank": rank, **record}) + "\n")

    original_update = modeling_focal.FocalPolicy.update
    original_loss = modeling_focal.consistency_loss

    def update(self) -> None:
        original_update(self)
        write(
            {
                "kind": "update",
                "ema_step": int(self.ema_step),
                "ema": sha(self.ema_model.state_dict().values()),
                "online": sha(self.model.state_dict().values()),
            }
        )

    def consistency_loss(objective, m0, m1, tau, r, *args, **kwargs):
        loss, logs = original_loss(objective, m0, m1, tau, r, *args, **kwargs)
        write({"kind": "loss", "m0": sha([m0]), "m1": sha([m1]), "tau": sha([tau, r]), "loss": float(loss)})
        return loss, logs

    modeling_focal.FocalPolicy.update = update
    modeling_focal.consistency_loss = consistency_loss


def exit_after_end_training() -> None:
    import logging
    import sys

    from accelerate import Accelerator

    original_end_training = Accelerator.end_training

    def end_training(self) -> None:
        multi = self.num_processes > 1
        original_end_training(self)
        if multi:
            logging.shutdown()
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)

    Accelerator.end_training = end_training


if __name__ == "__main__":
    if os.environ.get("FOCAL_PROBE_DIR"):
        install(Path(os.environ["FOCAL_PROBE_DIR"]))
    exit_after_end_training()
    from lerobot.scripts.lerobot_train import main

    main()
