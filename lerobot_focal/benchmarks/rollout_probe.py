"""LeRobot's own `lerobot-rollout`, with timers around each stage of its control loop.

Run as ``python -m lerobot_focal.benchmarks.rollout_probe EVENTS.json <lerobot-rollout arguments>``: it wraps
the methods below *on their classes* (so every instance LeRobot builds is timed), then calls
``lerobot.scripts.lerobot_rollout.main()`` unchanged. Nothing in the loop is re-implemented; only time stamps
are added. While the strategy's ``run`` is active every wrapped call appends ``(stage, start, end)``
(``time.perf_counter``, seconds) to a list, written to EVENTS.json when the process exits; calls outside
``run`` (connect, warm-up by ``setup``, the return to the start pose in ``teardown``) are not recorded.

Stages (what a user's loop spends its period on):

* ``get_observation``: `UR10e.get_observation` (arm state + camera frames), inside it ``camera_read``
  (the backend's ``read_cameras``: the twin renders the frame here; a real camera hands over its latest frame);
* ``inference``: LeRobot's ``SyncInferenceEngine.get_action``, inside it ``preprocessor`` (with
  ``depth_to_cloud``, focal's depth -> point cloud step), ``select_action`` (with ``network``: the one
  network evaluation of an action chunk, only on the steps that call the policy; for RGB inputs
  ``select_action`` also encodes the newest camera frame) and ``postprocessor``;
* ``send_action``: `UR10e.send_action` (safety filter, IK on the twin, servo command).
"""

from __future__ import annotations

import atexit
import functools
import json
import sys
import time
from pathlib import Path
from typing import Any

_EVENTS: list[tuple[str, float, float]] = []
_RECORDING = False


def _timed(stage: str, method: Any) -> Any:
    @functools.wraps(method)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        if not _RECORDING:
            return method(*args, **kwargs)
        start = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            _EVENTS.append((stage, start, time.perf_counter()))

    return wrapper


class _TimedPipeline:
    """A processor pipeline whose calls are timed; every other attribute is the pipeline's own."""

    def __init__(self, pipeline: Any, stage: str) -> None:
        self._pipeline = pipeline
        self._call = _timed(stage, pipeline.__call__)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self._call(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._pipeline, name)


def _wrap(cls: type, name: str, stage: str) -> None:
    setattr(cls, name, _timed(stage, getattr(cls, name)))


def install() -> None:
    """Wrap the stages' methods on their classes (idempotence is not needed: called once per process)."""
    from lerobot.rollout.inference.sync import SyncInferenceEngine
    from lerobot.rollout.strategies.core import RolloutStrategy

    from lerobot_focal.policy.depth_pointcloud_step import DepthToPointCloudProcessorStep
    from lerobot_focal.policy.modeling_focal import FocalPolicy
    from lerobot_focal.robots.ur10e.rtde.rtde_backend import RtdeBackend
    from lerobot_focal.robots.ur10e.twin.sim_backend import SimBackend
    from lerobot_focal.robots.ur10e.ur10e import UR10e

    _wrap(UR10e, "get_observation", "get_observation")
    _wrap(UR10e, "send_action", "send_action")
    _wrap(SimBackend, "read_cameras", "camera_read")
    _wrap(RtdeBackend, "read_cameras", "camera_read")
    _wrap(SyncInferenceEngine, "get_action", "inference")
    _wrap(FocalPolicy, "select_action", "select_action")
    _wrap(FocalPolicy, "sample_macro_trajectory", "network")
    _wrap(DepthToPointCloudProcessorStep, "observation", "depth_to_cloud")

    engine_init = SyncInferenceEngine.__init__

    @functools.wraps(engine_init)
    def init(self: Any, *args: Any, **kwargs: Any) -> None:
        engine_init(self, *args, **kwargs)
        self._preprocessor = _TimedPipeline(self._preprocessor, "preprocessor")
        self._postprocessor = _TimedPipeline(self._postprocessor, "postprocessor")

    SyncInferenceEngine.__init__ = init

    # Every strategy's subclass defines its own run(): wrap those LeRobot registered, at call time.
    for strategy in _subclasses(RolloutStrategy):
        if "run" in vars(strategy):
            strategy.run = _recording(strategy.run)


def _subclasses(cls: type) -> list[type]:
    import lerobot.rollout.strategies  # noqa: F401  (imports every strategy module)

    found, todo = [], [cls]
    while todo:
        for sub in todo.pop().__subclasses__():
            found.append(sub)
            todo.append(sub)
    return found


def _recording(run: Any) -> Any:
    @functools.wraps(run)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        global _RECORDING
        _RECORDING = True
        _EVENTS.append(("run", time.perf_counter(), time.perf_counter()))
        try:
            return run(*args, **kwargs)
        finally:
            _RECORDING = False

    return wrapper


def _write(path: Path) -> None:
    path.write_text(json.dumps({"events": _EVENTS}))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        print(__doc__)
        return 2
    events_path = Path(argv[0])
    install()
    atexit.register(_write, events_path)
    from lerobot.scripts.lerobot_rollout import main as rollout_main

    sys.argv = ["lerobot-rollout", *argv[1:]]
    rollout_main()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
