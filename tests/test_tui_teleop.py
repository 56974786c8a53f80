"""Teleop and Episodes screens on the sim-piper twin at 80x24: start teleop, record two episodes (labelled,
with a note), adjust the feedback gain, e-stop, then the Episodes screen lists and plots them."""

from __future__ import annotations

import asyncio

import numpy as np
from tui_helpers import SIZE, connect, make_app, screen_text, wait_for

from factr2_teleop.tui.teleop import joint_lines
from hardware.recording.reader import Recording


def test_joint_lines_fit_80_columns():
    lines = joint_lines(np.array([0.1, -3.5]), np.array([0.1, np.nan]), np.array([2.0, -1.0]),
                        np.array([0.05, 0.0]))
    assert len(lines) == 3 and all(len(x) <= 80 for x in lines)
    assert "<" in lines[2] and "?" in lines[2]  # beyond the bar range; unknown follower position


def test_teleop_records_two_episodes_listed_by_episodes_screen(tmp_path):
    async def go():
        app = make_app(tmp_path, rate_hz=250.0)
        async with app.run_test(size=SIZE) as pilot:
            await connect(pilot, app)
            await pilot.press("3")
            assert "teleop STOPPED" in screen_text(app)
            await pilot.press("r")  # refused: not running (one line, no crash)
            assert "teleop is not running" in app.runtime.messages[-1]
            await pilot.press("t")
            assert await wait_for(pilot, lambda: "phase coupled" in screen_text(app))
            await pilot.press("plus", "plus")
            assert app.teleop.gain == 0.05 and all(
                np.allclose(p.law.feedback.gain, 0.05) for p in app.teleop.loop.pairs
            )
            for outcome_key in ("s", "f"):
                await pilot.press("r")
                assert await wait_for(pilot, lambda: "REC * episode" in screen_text(app))
                await wait_for(pilot, lambda: app.teleop.rec_state().duration_s > 0.1)
                await pilot.press(outcome_key)
                assert await wait_for(pilot, lambda: "rec: idle" in screen_text(app))  # next refresh
            await pilot.press("n")
            await pilot.press(*"slow start", "enter")  # space types a space in the note field
            assert app.runtime.messages[-1].endswith("note added: slow start") and not app.runtime.estopped
            text = screen_text(app)
            assert "episodes done 2" in text and "loop" in text and "p99 period" in text
            assert "contact: free" in text
            await pilot.press("space")  # e-stop ends teleop and leaves both arms safe
            assert await wait_for(pilot, lambda: not app.teleop.running)
            assert all(d.in_safe_state for d in app.runtime.devices())
            assert await wait_for(pilot, lambda: "E-STOPPED" in screen_text(app))
            path = app.teleop.last_file  # teleop stopped: the session file is closed and complete
            assert app.teleop.recorder is None
            await pilot.press("4")
            assert await wait_for(pilot, lambda: "2 episode(s)" in screen_text(app))
            text = screen_text(app)
            assert " success " in text and " failure " in text and "0%" in text
            await pilot.press("enter")
            assert await wait_for(pilot, lambda: "follower q [rad]" in screen_text(app))
            assert "follower tau_ext estimate [N*m]" in screen_text(app)
            await pilot.press("q")
            await pilot.pause(0.5)
        rec = Recording(path)
        assert [e.outcome for e in rec.episodes] == ["success", "failure"]
        assert rec.cameras == ["scene"] and all(len(e.frames("scene")) > 0 for e in rec.episodes)
        assert rec.info.get("simulated") == "true" and rec.info.get("feedback_mode") == "ground_truth"
        assert any(e["kind"] == "note" and e["text"] == "slow start" for e in rec.events)

    asyncio.run(go())
