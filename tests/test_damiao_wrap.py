"""A Damiao motor reports its multi-turn position in a 16-bit field over +-PMAX: past PMAX the reading rolls
over by 2 * PMAX. The follower puts it back on the joint's turn (wrap_period_rad, hardware/wrap.py), both
ways across the roll-over and after a restart on the far side. SIMULATED: DamiaoEmulator on the virtual bus,
joint 6's PMAX register set to 3 rad and its limits across it (0.5 to 4.5 rad)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_damiao_driver import DT, Rig, limits

from hardware.damiao import protocol as D
from hardware.damiao.follower import HOLD_RESEND_S, DamiaoFollower

PMAX = 3.0  # rad: joint 6's position field, +-PMAX
J = 5
QUANT = 2 * PMAX / (2**16 - 1)  # rad: one count of the field


def test_reported_position_rolls_over_at_pmax():
    assert D.reported_position(2.9, PMAX) == pytest.approx(2.9)
    assert D.reported_position(3.2, PMAX) == pytest.approx(-2.8)
    assert D.reported_position(-3.2, PMAX) == pytest.approx(2.8)


@pytest.fixture
def rig():
    r = Rig()
    r.emu.registers[J][D.RID_PMAX] = PMAX
    r.emu.ranges[J] = dataclasses.replace(r.emu.ranges[J], pmax=PMAX)
    lim = limits()
    q_min, q_max = lim.q_min.copy(), lim.q_max.copy()
    q_min[J], q_max[J] = 0.5, 4.5
    r.f = DamiaoFollower(r.f.config, dataclasses.replace(lim, q_min=q_min, q_max=q_max), clock=r.clock)
    r.bank.q[J] = 2.5
    r.f.connect()
    yield r
    r.close()


def _read_at(r: Rig, q: float):
    """The follower's reading with joint 6 held at q [rad] (set on the simulated motor), and the raw field."""
    r.bank.q[J], r.bank.q_dot[J] = q, 0.0
    st = r.run(None, HOLD_RESEND_S + DT)  # on hold: the damping command (and its answer) every 20 ms
    return st.q[J], D.decode_feedback(r.f.decoder.latest[J], r.f.ranges[J])[2]


def test_a_joint_driven_across_the_roll_over_both_ways_reads_its_true_position(rig):
    assert rig.f.wrap_period_rad[J] == pytest.approx(2 * PMAX)  # from the PMAX register read at connect
    sweep = np.r_[np.arange(2.5, 3.5, 0.01), np.arange(3.5, 2.5, -0.01)]
    got, raw = np.array([_read_at(rig, q) for q in sweep]).T
    assert np.any(raw < 0)  # the field rolled over: -2.99 where the joint is at 3.01
    np.testing.assert_allclose(got, sweep, atol=2 * QUANT)
    assert rig.f.safety.jumps_rejected == 0 and rig.f.turns_unwrapped > 0


def test_a_restart_past_the_roll_over_reads_the_same_pose(rig):
    rig.f.disconnect()
    rig.bank.q[J] = 3.4  # reported as -2.6
    rig.f.connect()
    q, raw = _read_at(rig, 3.4)
    assert raw == pytest.approx(3.4 - 2 * PMAX, abs=2 * QUANT) and q == pytest.approx(3.4, abs=2 * QUANT)
