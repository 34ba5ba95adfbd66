"""Where the grid's runs execute: in this process's machine (sequentially, or a few at a time), or as Ray tasks.

Both executors hand every finished run to ``on_result`` as soon as it ends (the grid appends it to the
results file), retry a failed run ``retries`` times, and report a run that still fails as a failure record
instead of stopping the grid. Interrupting the driver keeps every result already written; the runs in flight
continue next time from their newest usable checkpoint (``resume``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

from .processes import GridStopped, stop_all
from .results import RunRecord
from .run import RunSpec, failure_record, run_one

OnResult = Callable[[RunRecord], None]


def _with_retries(spec: RunSpec, retries: int) -> RunRecord:
    for attempt in range(1, retries + 2):
        try:
            return run_one(spec)
        except GridStopped:
            raise
        except Exception as err:  # noqa: BLE001 - any failure of a run is recorded, never fatal to the grid
            logging.warning("run %s failed (attempt %d/%d): %s", spec.key, attempt, retries + 1, err)
            if attempt == retries + 1:
                return failure_record(spec, err, attempt)
    raise AssertionError("unreachable")


def run_local(specs: Sequence[RunSpec], on_result: OnResult, retries: int = 1, jobs: int = 1) -> None:
    """Runs are subprocesses (lerobot-train, analyze), so threads are enough to keep `jobs` of them going."""
    if jobs <= 1:
        try:
            for spec in specs:
                on_result(_with_retries(spec, retries))
        except KeyboardInterrupt:
            stop_all()
            raise
        return
    pool = ThreadPoolExecutor(max_workers=jobs)
    pending = {pool.submit(_with_retries, spec, retries) for spec in specs}
    try:
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                on_result(fut.result())
    except KeyboardInterrupt:
        # Queued runs first: a worker freed by stop_all() would otherwise start the next one (and collect its
        # data) before the pool is shut down.
        pool.shutdown(wait=False, cancel_futures=True)
        stop_all()  # in-flight lerobot-train processes end; their threads raise GridStopped, nothing is retried
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _ray_run(spec: RunSpec) -> RunRecord:
    """The Ray task body: run_one, raising on failure so Ray's own retry mechanism retries it."""
    return run_one(spec)


def run_ray(
    specs: Sequence[RunSpec],
    on_result: OnResult,
    retries: int = 1,
    address: str | None = None,
    cpus_per_run: float = 1.0,
    gpus_per_run: float = 0.0,
    init_kwargs: dict | None = None,
) -> None:
    """Each run is one Ray task with its own CPU/GPU reservation; Ray places and retries them.

    ``address=None`` starts a local Ray instance for this grid; ``"auto"`` or ``"ray://host:port"`` joins a
    running cluster (its nodes must see ``--work`` and have this package installed).
    """
    try:
        import ray
    except ImportError as err:
        raise SystemExit(
            "the Ray executor needs Ray: pip install 'lerobot_policy_focal[ray]' (or pip install ray), "
            "or run the grid without --executor ray"
        ) from err

    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=address, **(init_kwargs or {}))
    remote = ray.remote(num_cpus=cpus_per_run, num_gpus=gpus_per_run, max_retries=retries,
                        retry_exceptions=True)(_ray_run)
    refs = {remote.remote(spec): spec for spec in specs}
    try:
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            spec = refs.pop(done[0])
            try:
                on_result(ray.get(done[0]))
            except Exception as err:  # noqa: BLE001 - RayTaskError etc.: record and go on
                logging.warning("run %s failed after %d attempts: %s", spec.key, retries + 1, err)
                on_result(failure_record(spec, err, retries + 1))
    except KeyboardInterrupt:
        for ref in refs:
            ray.cancel(ref, force=True)
        raise
    finally:
        if started_here:
            ray.shutdown()
