import multiprocessing.util
import os
import subprocess
import sys
import time

import pytest

# Tests never reach a hub: everything they read they write first.
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
os.environ.setdefault("WANDB_MODE", "disabled")

# The suite runs on two pytest-xdist workers (pyproject's addopts: `-n 2 --dist loadscope`; `-n 0` runs it in one
# process). Each worker, and every process its tests start, gets one torch/OpenMP thread: two workers with two
# threads each oversubscribe a two-core machine (docs/benchmarks.md: two threads beside a grid run, 8x slower).
# xdist names the worker before this file is imported, so the setting reaches torch's first import.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("MKL_NUM_THREADS", "1")


# ---------------------------------------------------------------------------------------------- the fast tier
# `pytest -m fast` runs every test that starts no process and finishes within a few seconds: the edit-and-test loop
# (README, Tests). Every collected test gets the `fast` marker unless it is marked `slow`, `subprocess` or `heavy`, so
# a new test joins the tier by default. The tier keeps itself honest: while it runs, starting a process raises
# (and fails the test even if the test catches the error), a test over FAST_TEST_BUDGET_S fails, and a whole tier
# over FAST_TIER_BUDGET_S fails the session. Each failure says which marker the test needs.

#: Seconds one fast test may take (setup + call + teardown); generous for a loaded 2-core machine.
FAST_TEST_BUDGET_S = float(os.environ.get("LEROBOT_FOCAL_FAST_TEST_BUDGET_S", "30"))
#: Seconds the whole fast tier may take on the 2-core reference machine (README: < 3 min).
FAST_TIER_BUDGET_S = float(os.environ.get("LEROBOT_FOCAL_FAST_TIER_BUDGET_S", "180"))
#: Markers that keep a test out of the fast tier.
NOT_FAST = ("slow", "subprocess", "heavy")

_MARKERS = (
    "fast: added to every test not marked slow, subprocess or heavy; `pytest -m fast` is the quick tier",
    "subprocess: starts a process (a LeRobot command, a probe interpreter, a server): default suite, not the fast tier",
    f"heavy: in process but longer than the fast tier's {FAST_TEST_BUDGET_S:.0f} s per test: default suite only",
)


class SubprocessInFastTier(RuntimeError):
    """Raised when a test of the fast tier starts a process."""


_state: dict = {"fast": False, "test": None, "violations": {}, "started": None}


def pytest_configure(config: pytest.Config) -> None:
    for line in _MARKERS:
        config.addinivalue_line("markers", line)
    _state["fast"] = _selects_fast_tier(config.getoption("markexpr", ""))


def _selects_fast_tier(markexpr: str) -> bool:
    """Whether `-m markexpr` keeps a test marked `fast` alone and drops an unmarked one (`-m fast`, `-m "fast and
    not gpu"`...): then the tier's guards are on."""
    if not markexpr:
        return False
    from _pytest.mark.expression import Expression

    expr = Expression.compile(markexpr)
    return expr.evaluate(lambda name, **_: name == "fast") and not expr.evaluate(lambda name, **_: False)


@pytest.hookimpl(tryfirst=True)  # before pytest's own -m selection reads the markers
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if not any(item.get_closest_marker(name) for name in NOT_FAST):
            item.add_marker(pytest.mark.fast)


#: Standard-library modules that run a short probe command for the library that calls them (ctypes.util's
#: find_library runs `ldconfig -p`, platform.processor runs `uname -p`): not a process the test starts.
_PROBE_CALLERS = (os.sep + os.path.join("ctypes", "util.py"), os.sep + "platform.py")


def _called_from_a_probe() -> bool:
    frame = sys._getframe(2)
    while frame is not None:
        if frame.f_code.co_filename.endswith(_PROBE_CALLERS):
            return True
        frame = frame.f_back
    return False


def _refuse(what: str, original):
    def refuse(*args, **kwargs):
        if _called_from_a_probe():
            return original(*args, **kwargs)
        test = _state["test"] or "collection"
        command = args[1] if what == "subprocess.Popen" else (args[0] if args else "")
        message = (
            f"{test} started a process ({what}: {command!r}) in the fast tier (pytest -m fast), which runs none. "
            "Mark the test @pytest.mark.subprocess (a whole module: pytestmark = pytest.mark.subprocess) so that "
            "it runs in the default suite only; see tests/conftest.py."
        )
        _state["violations"].setdefault(test, message)
        raise SubprocessInFastTier(message)

    return refuse


_GUARDED = (
    (subprocess.Popen, "_execute_child", "subprocess.Popen"),  # subprocess.run/check_output, asyncio, ...
    (os, "system", "os.system"),
    (os, "fork", "os.fork"),
    (os, "forkpty", "os.forkpty"),
    (os, "posix_spawn", "os.posix_spawn"),
    (os, "posix_spawnp", "os.posix_spawnp"),
    (multiprocessing.util, "spawnv_passfds", "multiprocessing"),  # spawn and forkserver workers (fork: os.fork)
)


def _is_xdist_controller(config: pytest.Config) -> bool:
    """Whether this process only hands tests to xdist workers (which run them, with this file's guards)."""
    return config.pluginmanager.has_plugin("dsession")


def _is_xdist_worker(config: pytest.Config) -> bool:
    return hasattr(config, "workerinput")


@pytest.hookimpl(wrapper=True)
def pytest_runtestloop(session: pytest.Session):
    if not _state["fast"]:
        return (yield)
    _state["started"] = time.monotonic()
    if _is_xdist_controller(session.config):  # it runs no test, and may start a worker again
        return (yield)
    saved = [(owner, name, getattr(owner, name)) for owner, name, _ in _GUARDED if hasattr(owner, name)]
    for owner, name, what in _GUARDED:
        if hasattr(owner, name):
            setattr(owner, name, _refuse(what, getattr(owner, name)))
    try:
        return (yield)
    finally:
        for owner, name, original in saved:
            setattr(owner, name, original)


_setup_s = pytest.StashKey[float]()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem):
    _state["test"] = item.nodeid
    try:
        return (yield)
    finally:
        _state["test"] = None


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo):
    report = yield
    if not _state["fast"]:
        return report
    if report.when == "setup":
        item.stash[_setup_s] = call.duration
    if report.when != "call":
        return report
    problem = _state["violations"].pop(item.nodeid, None)  # failed even if the test caught the error
    spent = item.stash.get(_setup_s, 0.0) + call.duration
    if problem is None and spent > FAST_TEST_BUDGET_S:
        problem = (
            f"{item.nodeid} took {spent:.1f} s (setup + call), over the fast tier's {FAST_TEST_BUDGET_S:.0f} s per "
            "test (LEROBOT_FOCAL_FAST_TEST_BUDGET_S). Make it quicker, or mark it @pytest.mark.heavy so that it "
            "runs in the default suite only; see tests/conftest.py."
        )
    if problem is not None and not report.failed:
        report.outcome = "failed"
        report.longrepr = problem
    return report


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if not _state["fast"] or _state["started"] is None or not session.testscollected:
        return
    if _is_xdist_worker(session.config):  # the tier's wall time is the controller's
        return
    elapsed = time.monotonic() - _state["started"]
    if elapsed > FAST_TIER_BUDGET_S:
        message = (
            f"the fast tier took {elapsed:.0f} s, over its {FAST_TIER_BUDGET_S:.0f} s budget "
            "(LEROBOT_FOCAL_FAST_TIER_BUDGET_S): run `pytest -m fast --durations=15` and make the slowest quicker "
            "or mark them @pytest.mark.heavy"
        )
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        if reporter is not None:
            reporter.write_line(f"ERROR: {message}", red=True, bold=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
