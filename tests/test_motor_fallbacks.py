"""The motors' own fallbacks other than the Dynamixel watchdog (tests/test_dynamixel_watchdog.py): the Damiao
command timeout (register 9, 50 us units; the motor drops to damping), set and read back at connect, and the
one line for a motor that does not take it; the Piper, whose firmware offers none."""

from __future__ import annotations

import numpy as np
import pytest
from test_damiao_driver import DT, Q0, Rig

from hardware.damiao import protocol as D
from hardware.types import FollowerCommand


def test_damiao_timeout_read_back_at_connect():
    r = Rig(timeout_ms=50.0)
    r.f.connect()
    try:
        assert r.f.fallback == {i: pytest.approx(0.05) for i in [1, 2, 3, 4, 5, 6, 7]}
        assert all(regs[D.RID_TIMEOUT] == 1000 for regs in r.emu.registers)
        lines = r.f.fallback_lines()
        assert len(lines) == 1 and "id 1 50 ms" in lines[0] and "damping" in lines[0] and not r.f.warnings
    finally:
        r.close()


def test_damiao_motor_that_keeps_its_old_timeout_gets_one_line():
    r = Rig()
    r.emu.read_only_rids = frozenset({D.RID_TIMEOUT})  # a firmware that does not take the write
    r.f.connect()  # it still connects: the arm works, the operator is told what a crash would leave
    try:
        assert r.f.fallback[1] == 0
        said = [w for w in r.f.warnings if "command timeout" in w]
        assert len(said) == 1 and "id 1 (off)" in said[0] and "keeps its last MIT command" in said[0]
        assert said[0] in r.f.fallback_lines()
    finally:
        r.close()


def test_damiao_timeout_falls_back_at_its_deadline():
    r = Rig(timeout_ms=50.0)
    r.f.connect()
    r.run(FollowerCommand(q=Q0[:6] + 0.05), 0.1)
    t_last = r.emu.last_cmd_t.max()
    r.f.link.close()  # the app dies: no hold, no disable
    r.f.link = None
    for _ in range(30):
        r.clock.sleep(DT)
    assert r.emu.timeouts == 7 and np.all(r.bank.kp == 0.0) and np.all(r.bank.kd[:7] == 1.0)
    assert np.all(r.emu.t_timed_out <= t_last + 0.05 + 1e-9)  # each at its own deadline: last command + 50 ms
    r.emu_bus.shutdown()


# -- Piper: no command timeout to set; the twin does what the vendor's position loop does -------------------
@pytest.mark.parametrize("mode", ["position", "mit"])
def test_piper_keeps_its_last_command_when_the_host_dies(mode):
    from test_piper_driver import DT as PDT
    from test_piper_driver import Q0 as PQ0
    from test_piper_driver import Rig as PiperRig

    from hardware.sim.motors import MODE_MIT, MODE_POSITION

    r = PiperRig(mode=mode)
    r.f.connect()
    target = PQ0 + 0.05
    tau = np.full(6, 0.5) if mode == "mit" else None
    r.run(FollowerCommand(q=target, tau_ff=tau), 0.4)
    line = r.f.fallback_lines()[0]
    assert "no motor-side command timeout" in line and ("last joint target" in line if mode == "position"
                                                       else "last MIT command" in line)
    r.f.link.close()  # the app dies: nothing more on the bus
    r.f.link = None
    for _ in range(int(1.0 / PDT)):
        r.clock.sleep(PDT)
    if mode == "position":
        assert np.all(r.bank.mode[:6] == MODE_POSITION)
        np.testing.assert_allclose(r.bank.q_d[:6], target, atol=1e-3)  # still its last target, 1 s later
    else:
        assert np.all(r.bank.mode[:6] == MODE_MIT) and np.all(np.abs(r.bank.tau_ff[:6]) > 0.2)  # pushing
    r.emu_bus.shutdown()


# -- `factr2 doctor --rig RIG --fallbacks` ------------------------------------------------------------------
def test_doctor_reads_back_every_fallback_on_the_twin():
    from hardware.doctor import rig_fallbacks
    from hardware.rigs import load_rig

    chk = rig_fallbacks(load_rig("sim-yam"))
    text = [f.line() for f in chk.findings]
    assert len(text) == 2 and all(t.startswith("OK") for t in text), text
    assert "100 ms" in text[0] and "id 7 50 ms" in text[1]


def test_doctor_line_for_a_servo_that_refuses_its_watchdog():
    from hardware.connect import open_rig
    from hardware.doctor import fallback_check

    s = open_rig("sim-piper", connect=False)
    try:
        s.twin.devices["leader"].emulator.servo(3).has_watchdog = False  # as firmware before v38
        for d in list(s.leaders.values()) + list(s.followers.values()):
            d.connect()
        chk = fallback_check(s)
    finally:
        s.close()
    warn = [f.line() for f in chk.findings if f.level == "warn" and f.subject == "leader"]
    assert len(warn) == 1 and "servo id 3" in warn[0] and "until its power is cut" in warn[0], warn
    ok = [f.line() for f in chk.findings if f.level == "ok"]
    assert any("[1, 2, 4, 5, 6]" in t for t in ok), ok
