"""Shared helpers for the TUI pilot tests (Textual App.run_test on the sim-piper twin, 80x24)."""

from __future__ import annotations

import time

from machine_speed import budget
from textual.widgets import Static

from factr2_teleop.tui.app import Factr2App
from factr2_teleop.tui.runtime import RigRuntime

SIZE = (80, 24)


def make_app(tmp_path, **kw) -> Factr2App:
    kw.setdefault("cal_minutes", 0.1)
    kw.setdefault("cal_epochs", 2)
    kw.setdefault("cal_samples_per_epoch", 1024)
    return Factr2App(RigRuntime("sim-piper", pace=0), out_dir=tmp_path, **kw)


def screen_text(app) -> str:
    return "\n".join(str(w.render()) for w in app.screen.query(Static))


async def wait_for(pilot, cond, timeout_s: float = 20.0, step_s: float = 0.1) -> bool:
    """Whether cond() came true within timeout_s [s, sized on the dev VM; scaled to this machine, #53]."""
    t_end = time.monotonic() + budget(timeout_s)
    while time.monotonic() < t_end:
        if cond():
            return True
        await pilot.pause(step_s)
    return cond()


async def connect(pilot, app) -> None:
    await pilot.press("1", "c")
    assert await wait_for(pilot, lambda: app.runtime.connected), app.runtime.messages[-3:]
