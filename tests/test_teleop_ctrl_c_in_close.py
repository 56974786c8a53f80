"""A Ctrl-C that comes while `factr2 teleop` puts the arms down and closes the recording (the loop ended by
itself, or the operator's second Ctrl-C) is said, not raised: before, KeyboardInterrupt escaped from the
recording's close, leaving it unclosed and the rig open (seen on a slowed core, where the loop ended before
the operator's Ctrl-C came). On the twin (SIMULATED, real time), deterministic: the SIGINT is sent from
inside the close."""

from __future__ import annotations

import os
import signal

import pytest

from hardware.dynamixel import protocol as p


def test_ctrl_c_during_the_close_is_held(tmp_path, monkeypatch, request, capsys):
    import hardware.connect as connect
    from factr2_teleop.cli import build_parser
    from factr2_teleop.commands import teleop
    from factr2_teleop.session.teleop import TeleopSession

    got, real_open, real_close = {}, connect.open_rig, TeleopSession.close_recording
    prev = signal.signal(signal.SIGINT, signal.default_int_handler)  # Python's own Ctrl-C (restored after)
    request.addfinalizer(lambda: signal.signal(signal.SIGINT, prev))

    def open_rig(*a, **k):
        got["session"] = real_open(*a, **k)
        return got["session"]

    def close_with_ctrl_c(self, *a, **k):
        os.kill(os.getpid(), signal.SIGINT)  # the operator's Ctrl-C, as the recording closes
        return real_close(self, *a, **k)

    monkeypatch.setattr(connect, "open_rig", open_rig)
    monkeypatch.setattr(TeleopSession, "close_recording", close_with_ctrl_c)
    args = build_parser().parse_args(["teleop", "--rig", "sim-yam", "--seconds", "0.3", "--record",
                                      str(tmp_path), "--no-cameras"])
    try:
        out = teleop.execute(args)
    except KeyboardInterrupt:
        pytest.fail("KeyboardInterrupt escaped from the safe stop")
    assert out["recording"] is not None and out["status"].error is None
    assert "Ctrl-C: already stopping" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
    s = got["session"]
    for name in s.leaders:
        for servo in s.twin.devices[name].emulator.servos:
            assert servo.get(p.ADDR_TORQUE_ENABLE) == 0, f"{name}: servo {servo.id} left torque on"
