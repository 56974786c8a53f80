"""Calibration wizard on the sim-piper twin at 80x24: checklist, a short replay (0.1 min), 2 training
epochs, the report (accuracy vs baselines, diagnosis), activation; plus the abort on unexpected contact."""

from __future__ import annotations

import asyncio
import threading
import time

import numpy as np
import torch
from machine_speed import budget
from tui_helpers import SIZE, connect, make_app, screen_text, wait_for

from factr2_teleop.tui.calib_ctl import CalibrationRun, _with_checkpoint, shorten
from factr2_teleop.tui.calibration import report_lines, step_lines
from factr2_teleop.tui.runtime import RigRuntime
from factr2_teleop.tui.teleop import last_link
from hardware.rigs.rig import load_rig

torch.set_num_threads(1)


def test_step_lines_and_report_lines():
    assert step_lines("replay")[:3] == [
        "[x] plan the coverage trajectory",
        "[x] move to the start pose",
        "[>] replay the free-motion trajectory",
    ]
    assert step_lines("aborted", "replay")[2].startswith("[!]")
    rep = {"units": "N*m", "methods": {"next": {"free_l1_mean": 0.1, "contact_l1_mean": None}}}
    diag = {
        "verdict": "added 1 effect(s)",
        "joints": ["joint1"],
        "steps": [
            {"added": None},
            {
                "added": {
                    "effect": "coulomb_friction",
                    "joint": 0,
                    "evidence": {"heldout_l1_joint_before": 0.27, "heldout_l1_joint_after": 0.12},
                }
            },
        ],
    }
    text = "\n".join(report_lines(rep, diag))
    assert (
        "next" in text
        and "0.1000" in text
        and "coulomb_friction on joint1: held-out L1 0.270 -> 0.120" in text
    )


def test_with_checkpoint_edits_only_the_named_follower(tmp_path):
    text = load_rig("sim-bimanual-piper").path.read_text()
    rig = load_rig("sim-bimanual-piper")
    name = rig.followers[1].name
    out = tmp_path / "r.toml"
    out.write_text(_with_checkpoint(text, name, str(tmp_path / "next")))
    r2 = load_rig(out)
    assert r2.device(name).next_checkpoint == str(tmp_path / "next")
    assert r2.followers[0].next_checkpoint is None


def test_shorten_ends_at_rest_and_returns_home():
    from calibration.trajectories import coverage_trajectory

    tr = coverage_trajectory(np.full(2, -1.0), np.full(2, 1.0), np.full(2, 1.0), np.zeros(2), minutes=1.0)
    short = shorten(tr, 0.05)
    assert short.duration_s < tr.duration_s and np.allclose(short.q[-1], short.q[0])
    assert np.max(np.abs(np.diff(short.q, axis=0))) < 0.05  # no jumps where it was cut


def test_wizard_runs_a_short_calibration_and_activates_it(tmp_path):
    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("2")
            assert "NEXT calibration unavailable: no rig connected" in screen_text(app)
            await connect(pilot, app)
            await pilot.press("2", "g")
            assert "tick every checklist item" in app.runtime.messages[-1] and app.calibration is None
            await pilot.press("w", "a", "e")
            assert screen_text(app).count("[x]") == 3
            await pilot.press("g")
            assert await wait_for(
                pilot, lambda: app.calibration.state.step in ("done", "failed", "aborted"), 180
            )
            assert app.calibration.state.step == "done", app.calibration.state.line
            assert await wait_for(pilot, lambda: "ACTIVE for" in screen_text(app))
            text = screen_text(app)
            for word in (
                "held-out free motion, mean |tau_ext|",
                "next",
                "observer",
                "filic",
                "raw",
                "ridge",
                "diagnosis:",
                "ACTIVE for follower",
            ):
                assert word in text
            ck = app.calibration.state.checkpoint
            assert app.runtime.rig.followers[0].next_checkpoint == ck
            assert load_rig(app.calibration.state.rig_file).followers[0].next_checkpoint == ck
            assert all(d.in_safe_state for d in app.runtime.devices()) and app.runtime.activity is None
            # the live replay view, drawn from the torques this run recorded: the lockstep replay is over
            # before the first screen poll (press() waits for idle), so its state is set back to mid-replay
            st = app.calibration.state
            assert len(st.tau) > 10
            st.step, st.progress, st.eta_s, st.line = "replay", 0.5, 3.0, "replay: 4.0 / 8.0 s of trajectory"
            assert await wait_for(
                pilot, lambda: all(w in screen_text(app) for w in ("replay: ", "measured torque", "ETA"))
            )
            await pilot.press("q")
            await pilot.pause(0.5)

    asyncio.run(go())


def test_replay_aborts_on_unexpected_contact(tmp_path):
    rt = RigRuntime("sim-piper", pace=0)
    rt.connect()
    try:
        run = CalibrationRun(rt, tmp_path, minutes=0.1, epochs=1)
        th = threading.Thread(target=run.run_all)
        th.start()
        t_end = time.monotonic() + budget(60.0)  # sized on the dev VM (#53)
        while run.state.step != "replay" and th.is_alive() and time.monotonic() < t_end:
            time.sleep(0.05)
        while len(run.state.residual) < 30 and th.is_alive():
            time.sleep(0.05)
        rt.session.twin.push(last_link("piper"), [0.0, 0.0, -150.0], 2.0, "follower")  # someone leans on it
        th.join(60)
        st = run.snapshot()
        assert st.step == "aborted" and "unexpected contact" in st.error and st.failed_at == "replay"
        assert rt.session.followers["follower"].in_safe_state and rt.activity is None
    finally:
        rt.shutdown()
