"""Record what focal's `predict_action_chunk` is given and returns inside a real ``lerobot-rollout`` (test support,
not product code).

With ``FOCAL_DUMP_RTC=<dir>`` set, every call in this process writes ``<dir>/call_<n>.npz`` with the previous
chunk's leftover LeRobot's RTC engine passed (empty when None), the inference delay and the returned chunk,
then returns that chunk unchanged: the rollout's code path is untouched (the wrapper keeps the signature that
LeRobot's `supports_rtc_inference` checks).
"""

import os

if os.environ.get("FOCAL_DUMP_RTC"):
    import functools
    import itertools
    from pathlib import Path

    import numpy as np

    from lerobot_focal.policy.modeling_focal import FocalPolicy

    _dir = Path(os.environ["FOCAL_DUMP_RTC"])
    _dir.mkdir(parents=True, exist_ok=True)
    _count = itertools.count()
    _predict = FocalPolicy.predict_action_chunk

    @functools.wraps(_predict)
    def _recording_predict(self, batch, *args, **kwargs):
        out = _predict(self, batch, *args, **kwargs)
        prev = kwargs.get("prev_chunk_left_over")
        np.savez(
            _dir / f"call_{next(_count):04d}.npz",
            prev=np.zeros((0,)) if prev is None else prev.detach().cpu().numpy(),
            delay=np.array(-1 if kwargs.get("inference_delay") is None else kwargs["inference_delay"]),
            chunk=out.detach().cpu().numpy(),
        )
        return out

    FocalPolicy.predict_action_chunk = _recording_predict
