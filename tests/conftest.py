"""Shared test fixtures: where the shared data lives, small helpers."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("FACTR2_SHARED", REPO.parent / "shared"))
UR5_DIR = SHARED / "data" / "ur5_kufieta2014"


@pytest.fixture
def ur5_dir() -> Path:
    """The real UR5 logs in ../shared; tests that need them skip cleanly when absent."""
    if not (UR5_DIR / "TEST.npz").exists():
        pytest.skip(f"real UR5 logs not found at {UR5_DIR}")
    return UR5_DIR
