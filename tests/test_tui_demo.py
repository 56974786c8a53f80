"""`factr2 demo`'s live view (factr2_teleop.tui.demo_view) at 80x24 on the sim-piper twin (SIMULATED,
lockstep, ground-truth feedback: no NEXT training): driven through commands/demo.py's real call, so the
summary and the JSON after the view are checked too."""

from __future__ import annotations

import asyncio
import json
import re
import sys

import pytest
from tui_helpers import SIZE, screen_text, wait_for

import factr2_teleop.commands.demo as demo_cmd
from factr2_teleop.cli import main
from factr2_teleop.tui.demo_view import DemoApp

ARGS = ["demo", "--clock", "lockstep", "--rate", "250", "--mode", "ground_truth"]


def _ticks(text: str) -> int:
    m = re.search(r"(\d+) ticks", text)
    return int(m.group(1)) if m else -1


@pytest.fixture
def live(monkeypatch, capsys):
    """install(script): commands/demo.py thinks it runs in a terminal, and its view is the DemoApp under a
    pilot running script(pilot, app, run, worker)."""
    seen = {}

    def install(script, linger_s=0.2):
        monkeypatch.setattr(sys.stdout, "isatty", lambda: True)  # capsys' streams, once the test runs
        monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
        def show(run, worker):
            async def go():
                app = DemoApp(run, worker, linger_s=linger_s)
                async with app.run_test(size=SIZE) as pilot:
                    await script(pilot, app, run, worker)
                    assert await wait_for(pilot, lambda: app.return_value is not None, 10.0)
                seen["app"] = app
                return app.return_value

            return asyncio.run(go())

        monkeypatch.setattr(demo_cmd, "tui_view", lambda: show)
        return seen

    return install


def test_live_numbers_then_space_stops_safely_and_summary_follows(tmp_path, live, capsys):
    got = {}

    async def script(pilot, app, run, worker):
        assert await wait_for(pilot, lambda: "phase coupled" in screen_text(app)
                              and _ticks(screen_text(app)) > 300, 20.0), screen_text(app)
        first = screen_text(app)
        assert await wait_for(pilot, lambda: _ticks(screen_text(app)) > _ticks(first) + 50, 10.0)
        got["live"] = screen_text(app)
        await pilot.press("space")
        confirmed = "** E-STOP: leader torque OFF, follower HOLD **"
        assert await wait_for(pilot, lambda: confirmed in screen_text(app), 10.0)
        assert not worker.is_alive()
        assert run.leader.in_safe_state and run.follower.in_safe_state
        got["stopped"] = screen_text(app)
        await pilot.pause(0.5)  # stays up after an e-stop (the user reads it) until q
        assert app.return_value is None
        await pilot.press("q")

    live(script)
    out = tmp_path / "demo.json"
    assert main(ARGS + ["--seconds", "30", "--json", str(out)]) == 0
    text = got["live"]
    assert "[SIMULATED]" in text and "SIMULATED twin" in text and "feedback ground_truth" in text
    assert "loop 250 Hz (sim clock), p99 period 4.00 ms" in text  # lockstep: exact period
    assert re.search(r"task (free|reach|contact|wipe|release)", text) and "contact: " in text
    assert re.search(r"t 00:0\d\.\d of 00:30\.0, \d+\.\d s left", text)
    assert "leader q [rad]" in text and "F tau_ext [N*m]" in text
    assert re.search(r"\n1  \[[-|#<>]+\] *[+-]\d\.\d\d", text)  # joint 1: a bar and a number
    assert all(len(line) <= SIZE[0] for line in text.splitlines())
    assert "E-STOPPED" in got["stopped"]
    cap = capsys.readouterr()
    assert "live view: emergency stop: leader torque OFF, follower HOLD" in cap.err
    assert "SIMULATED demo (ground_truth, lockstep clock, 30 s):" in cap.out
    d = json.loads(out.read_text())
    assert d["mode"] == "ground_truth" and d["max_command_violation"] == 0
    assert 300 < d["ticks"] < 30 * 250 / 2  # cut short by the e-stop


def test_view_returns_by_itself_when_the_run_ends(tmp_path, live, capsys):
    async def script(pilot, app, run, worker):
        assert await wait_for(pilot, lambda: "ENDED" in screen_text(app), 20.0)
        assert "phase stopped" in screen_text(app)

    seen = live(script)
    out = tmp_path / "demo.json"
    assert main(ARGS + ["--seconds", "2", "--json", str(out)]) == 0
    assert seen["app"].return_value == "finished"
    cap = capsys.readouterr()
    assert "live view:" not in cap.err and "SIMULATED demo (ground_truth" in cap.out
    assert json.loads(out.read_text())["ticks"] >= 2 * 250 * 0.95


def test_q_mid_run_stops_safely_and_summary_follows(tmp_path, live, capsys):
    async def script(pilot, app, run, worker):
        assert await wait_for(pilot, lambda: "phase coupled" in screen_text(app), 20.0), screen_text(app)
        await pilot.press("q")
        assert await wait_for(pilot, lambda: app.return_value is not None, 10.0)
        assert not worker.is_alive() and run.leader.in_safe_state and run.follower.in_safe_state

    seen = live(script)
    assert main(ARGS + ["--seconds", "30"]) == 0
    assert seen["app"].return_value == "stopped by the user, leader torque OFF, follower HOLD"
    cap = capsys.readouterr()
    assert "live view: stopped by the user" in cap.err and "SIMULATED demo (ground_truth" in cap.out
