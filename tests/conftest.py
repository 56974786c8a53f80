"""Shared test fixtures: where the shared data lives, small helpers."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

import pytest

# the recordings' array and frame caches of this test session go to a folder of its own (subprocesses
# inherit it), not into the user's ~/.cache/factr2; the demo's NEXT cache ($FACTR2_CACHE) stays shared
_CACHE = tempfile.mkdtemp(prefix="factr2-test-recording-cache-")
os.environ.setdefault("FACTR2_RECORDING_CACHE", _CACHE)
atexit.register(shutil.rmtree, _CACHE, True)

# The tests run on two pytest-xdist workers (pyproject.toml). What keeps the workers apart:
# - the loop's CPU claims (hardware/realtime.py) live under $XDG_RUNTIME_DIR: a folder per worker, so a loop
#   pinned by one worker's test does not move the other worker's threads off its CPU;
# - a test marked `exclusive` runs alone: it holds a file lock exclusively that every other test holds
#   shared while it runs (CPU pinning, and real-time runs whose checks are timing under a fault);
# - the test's CPU affinity is put back after it (a training that kept off a claimed CPU leaves none behind).
_WORKER = os.environ.get("PYTEST_XDIST_WORKER")
if _WORKER:
    _RUNTIME = tempfile.mkdtemp(prefix=f"factr2-test-runtime-{_WORKER}-")
    os.environ["XDG_RUNTIME_DIR"] = _RUNTIME
    atexit.register(shutil.rmtree, _RUNTIME, True)
EXCLUSIVE_FILES = {
    "test_loop_cpu_claims.py",  # pins the loop and reads the process's affinity
    "test_spawn_normal.py",  # needs two CPUs of its own
    "test_crash_rollout.py",  # a frozen app must come back at the soft start within its budget
    "test_degrade.py",  # judges the rate a loop holds
    "test_demo_hold.py",  # the demo's scripted hold and resume, timed by the scenario
    "test_recording_process.py",  # real-time camera frames counted against the clock, a writer stopped 0.4 s
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in EXCLUSIVE_FILES:
            item.add_marker(pytest.mark.exclusive)


@pytest.fixture(autouse=True)
def _workers_apart(request, tmp_path_factory):
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    if not _WORKER:
        yield
    else:
        import fcntl

        exclusive = request.node.get_closest_marker("exclusive") is not None
        with open(tmp_path_factory.getbasetemp().parent / "exclusive.lock", "a") as f:
            fcntl.flock(f, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
            try:
                yield
            finally:
                fcntl.flock(f, fcntl.LOCK_UN)
    if affinity is not None and os.sched_getaffinity(0) != affinity:
        os.sched_setaffinity(0, affinity)


REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("FACTR2_SHARED", REPO.parent / "shared"))
UR5_DIR = SHARED / "data" / "ur5_kufieta2014"


@pytest.fixture
def ur5_dir() -> Path:
    """The real UR5 logs in ../shared; tests that need them skip cleanly when absent."""
    if not (UR5_DIR / "TEST.npz").exists():
        pytest.skip(f"real UR5 logs not found at {UR5_DIR}")
    return UR5_DIR


def pytest_report_header(config):
    from machine_speed import slowdown

    return f"machine slowdown against the dev VM: {slowdown():.2f} (tests/machine_speed.py scales budgets)"


@pytest.fixture(scope="session")
def machine_slowdown() -> float:
    """This machine's slowdown against the dev VM the time budgets were sized on (tests/machine_speed.py)."""
    from machine_speed import slowdown

    return slowdown()


@pytest.fixture(scope="session")
def wipe_state_runs(tmp_path_factory):
    """runs[method]: a tiny state policy on one scripted wipe demonstration, collected and trained once per
    session on first use (tests/rollout_helpers.py WipeStateRuns); the rollout tests only read it."""
    from tests.rollout_helpers import WipeStateRuns

    return WipeStateRuns(tmp_path_factory.mktemp("wipe_state"))
