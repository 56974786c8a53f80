"""`factr2 teleop` ending normally (--seconds elapsed; q and Ctrl-C take the same path) puts the arms down
through their drivers at once, before the recording closes: on the twin (SIMULATED, real time) no motor
is left without commands long enough to fall back by its own timeout after the loop's last tick (a slow
start-up may trip a Bus Watchdog before the first: the driver re-arms it, docs/safety.md), every leader
servo ends torque off at 0 A, and a Damiao follower ends disabled by its driver."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from hardware.dynamixel import protocol as p

CLOSE_EXTRA_S = 0.4  # s added to the recording's close: longer than a leader's Bus Watchdog (0.1 s)


@pytest.mark.parametrize("rig,end", [("sim-piper", "seconds"), ("sim-yam", "seconds"), ("sim-yam", "ctrl-c")])
def test_teleop_end_puts_the_arms_down_before_the_recording_closes(rig, end, tmp_path, monkeypatch, request):
    import hardware.connect as connect
    from factr2_teleop.cli import build_parser
    from factr2_teleop.commands import teleop
    from factr2_teleop.session.teleop import TeleopSession

    got = {}
    real_open, real_close = connect.open_rig, TeleopSession.close_recording

    def open_rig(*a, **k):
        got["session"] = connect_session = real_open(*a, **k)
        return connect_session

    def slow_close(self, *a, **k):  # a recording that takes its time to finish (a loaded machine, a camera)
        got.setdefault("t_end", self.loop.snapshot().t)  # the loop's last tick [s, rig clock]
        time.sleep(CLOSE_EXTRA_S)
        return real_close(self, *a, **k)

    monkeypatch.setattr(connect, "open_rig", open_rig)
    monkeypatch.setattr(TeleopSession, "close_recording", slow_close)
    if end == "ctrl-c":  # the operator's Ctrl-C while the status line runs (the main thread's SIGINT)
        real_watch = teleop._watch
        # Python's own Ctrl-C handler, whatever an earlier test of the run left installed (restored after)
        prev = signal.signal(signal.SIGINT, signal.default_int_handler)
        request.addfinalizer(lambda: signal.signal(signal.SIGINT, prev))

        def watch(loop):
            threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGINT)).start()
            real_watch(loop)

        monkeypatch.setattr(teleop, "_watch", watch)
    secs = "1.0" if end == "seconds" else "30"
    args = build_parser().parse_args(["teleop", "--rig", rig, "--seconds", secs, "--record", str(tmp_path),
                                      "--no-cameras"])
    out = teleop.execute(args)
    run = out["timing"]  # Ctrl-C ended it, not the 30 s: the loop's own time (its ticks x mean period), which
    assert run.ticks / run.rate_hz < 15.0  # a slow machine's start-up and close do not add to (#53)
    assert out["recording"] is not None and out["status"].error is None
    _assert_put_down_after(got["session"], got["t_end"])


def test_teleop_end_puts_the_arms_down_from_the_loops_thread(tmp_path, monkeypatch):
    """The loop ends by itself (--seconds) and the main thread notices it late (a slowed core: the loop's
    restores and the hand-off to the main thread took over 100 ms, issue #53; 0.3 s here): the loop's own
    thread put the arms down as it ended, so no leader servo's Bus Watchdog and no Damiao motor's timeout
    fell back before torque off."""
    import hardware.connect as connect
    from factr2_teleop.cli import build_parser
    from factr2_teleop.commands import teleop

    got = {}
    real_open, real_watch = connect.open_rig, teleop._watch

    def open_rig(*a, **k):
        got["session"] = connect_session = real_open(*a, **k)
        return connect_session

    def late_watch(loop):
        real_watch(loop)
        got["t_end"] = loop.snapshot().t  # the loop's end [s, rig clock]
        time.sleep(3 * CLOSE_EXTRA_S / 4)  # the main thread comes back late (> 100 ms)

    monkeypatch.setattr(connect, "open_rig", open_rig)
    monkeypatch.setattr(teleop, "_watch", late_watch)
    args = build_parser().parse_args(["teleop", "--rig", "sim-yam", "--seconds", "1.0"])
    teleop.execute(args)
    _assert_put_down_after(got["session"], got["t_end"])


def _assert_put_down_after(s, t_end: float) -> None:
    """No motor of the rig session s fell back by its own timeout after t_end [s, rig clock]; every leader
    servo torque off at 0 A, every Damiao follower disabled."""
    off = s.twin.rig_time() - s.twin.t  # rig clock - twin clock [s]
    for name in s.leaders:
        emu = s.twin.devices[name].emulator
        late = [deadline for _id, deadline, _t in emu.watchdog_trips if deadline > t_end]
        assert late == [], f"{name}: a servo's Bus Watchdog fired after the loop: the app left it waiting"
        for servo in emu.servos:
            assert servo.get(p.ADDR_TORQUE_ENABLE) == 0, f"{name}: servo {servo.id} left torque on"
            assert servo.get(p.ADDR_GOAL_CURRENT, signed=True) == 0, f"{name}: servo {servo.id} not at 0 A"
    for name, spec in ((f.name, f) for f in s.rig.followers):
        emu = s.twin.devices[name].emulator
        if spec.driver == "damiao":
            late = [x + off for _k, x in emu.timeout_log if x + off > t_end]
            assert late == [], f"{name}: a motor fell back to damping before the driver disabled it"
            assert not emu.enabled.any(), f"{name}: the driver's close leaves every motor disabled"
