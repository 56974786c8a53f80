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
