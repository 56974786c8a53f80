"""Rig screen on the sim-piper twin at 80x24: connect, live status, doctor, e-stop, another rig, safe quit."""

from __future__ import annotations

import asyncio

import numpy as np
from tui_helpers import SIZE, connect, make_app, screen_text, wait_for

from factr2_teleop.tui.rig import device_lines
from factr2_teleop.tui.runtime import DeviceStatus, status_words
from hardware.types import STATUS_ENABLED, STATUS_OVERTEMP, STATUS_STALE


def test_status_words_and_device_lines():
    assert status_words(np.array([STATUS_ENABLED, STATUS_OVERTEMP | STATUS_STALE, 0])) == [
        "overtemp j2",
        "stale j2",
    ]
    d = DeviceStatus(
        "follower",
        "follower",
        "piper",
        "piper",
        "can0",
        connected=True,
        mode="position",
        safe=False,
        temp_max_c=41.0,
        errors=["overtemp j2"],
        read_ms=0.4,
    )
    text = "\n".join(device_lines([d]))
    assert "ACTIVE" in text and "41C" in text and "overtemp j2" in text and "0.4ms" in text
    assert all(len(line) <= 80 for line in text.splitlines())


def test_rig_screen_connect_doctor_estop_and_quit(tmp_path):
    async def go():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            text = screen_text(app)
            assert "sim-piper [SIM]" in text and "disconnected" in text and "SIMULATED" in text
            await pilot.press("d")  # doctor while disconnected: probes the twin's servos over the wire
            ok = await wait_for(pilot, lambda: "sync read of 7 servos" in screen_text(app), 30)
            assert ok, (app.runtime.messages[-3:], screen_text(app))
            assert "XL330-M288" in screen_text(app) and "ERROR" not in screen_text(app)
            await connect(pilot, app)
            assert await wait_for(pilot, lambda: all(np.isfinite(d.read_ms) for d in app.runtime.statuses()))
            await pilot.pause(0.3)
            text = screen_text(app)
            assert (
                "leader     leader   UP    current" in text and "follower   follower UP    position" in text
            )
            assert (
                "SAFE" in text and "25C" in text
            )  # idle arms are held safe; the follower reports temperature
            await pilot.press("space")
            assert "E-STOP: leader torque OFF, follower HOLD" in app.runtime.messages[-1]
            assert await wait_for(pilot, lambda: "E-STOPPED" in screen_text(app))
            assert all(d.in_safe_state for d in app.runtime.devices())
            await pilot.press("o")  # rig picker: pick sim-yam (disconnects first)
            await pilot.pause()
            idx = app.runtime.available_rigs().index("sim-yam")
            await pilot.press(*(["down"] * idx), "enter")
            assert await wait_for(pilot, lambda: "sim-yam [SIM]" in screen_text(app))
            assert not app.runtime.connected and app.runtime.rig.name == "sim-yam"
            await pilot.press("q")
            await pilot.pause(0.5)
        assert app.runtime.session is None and "arms left safe" in " ".join(app.runtime.messages)

    asyncio.run(go())


def test_real_rig_without_hardware_says_so_in_one_line(tmp_path):
    from factr2_teleop.tui.app import Factr2App
    from factr2_teleop.tui.runtime import RigRuntime

    async def go():
        app = Factr2App(RigRuntime("piper"), out_dir=tmp_path, light=True)  # light terminal theme
        async with app.run_test(size=SIZE) as pilot:
            assert app.theme == "textual-light"
            assert "piper [REAL]" in screen_text(app) and "REAL HARDWARE" in screen_text(app)
            await pilot.press("c")
            assert await wait_for(
                pilot, lambda: app.runtime.messages[-1].split(" ", 1)[1].startswith("connect:")
            )
            assert not app.runtime.connected and "fix:" in app.runtime.messages[-1]
            await pilot.press("2")
            assert "NEXT calibration unavailable: no rig connected" in screen_text(app)
            await pilot.press("3", "t")
            assert await wait_for(pilot, lambda: "no rig connected" in app.runtime.messages[-1])
            await pilot.press("q")
            await pilot.pause(0.3)

    asyncio.run(go())
