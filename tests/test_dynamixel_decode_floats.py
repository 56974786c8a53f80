"""DynamixelLeader's all-fresh decode (one struct unpack, plain floats) against the numpy decode it replaced,
bit for bit, on replies from the emulator over a pty: with and without current, with the trigger servo,
moving joints (the tick delta unwrapped across the turn) and any raw field values."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_dynamixel_leader import make

from hardware.dynamixel import protocol as p

HALF, MASK = p.TICKS_PER_REV // 2, p.TICKS_PER_REV - 1
_DTYPES = {True: np.dtype([("cur", "<i2"), ("vel", "<i4"), ("pos", "<i4")]),
           False: np.dtype([("vel", "<i4"), ("pos", "<i4")])}


def _numpy_decode(leader, got):
    """(q, q_dot, current, tau_m, q_servo) as the numpy decode computed them (structured view)."""
    n, rc, ids = leader.n_joints, leader.config.read_current, leader.read_ids
    rec = np.frombuffer(b"".join([got[i][0] for i in ids]), dtype=_DTYPES[rc])
    ticks = rec["pos"].astype(np.int64)
    d = ((ticks - np.asarray(leader._ticks_prev, np.int64) + HALF) & MASK) - HALF
    q_servo = np.asarray(leader._q_servo, float) + d * p.RAD_PER_TICK
    cur = leader.signs * rec["cur"][:n] * leader.amps_per_unit if rc else leader.last_state.current
    tau = leader.k * cur if rc else leader.last_state.tau_m
    q = leader.signs * (q_servo[:n] - leader.offsets)
    qd = leader.signs * (rec["vel"][:n] * p.RAD_S_PER_VELOCITY_UNIT)
    return q, qd, cur, tau, q_servo


def _same(a, b) -> bool:
    return np.asarray(a, float).tobytes() == np.asarray(b, float).tobytes()


@pytest.mark.parametrize("gripper", [False, True])
@pytest.mark.parametrize("read_current", [True, False])
def test_decode_of_emulator_replies_is_the_numpy_decode(gripper, read_current):
    bank, emu, leader = make(gripper=gripper)
    leader.config.read_current = read_current
    leader.field = ((p.FEEDBACK_START, p.FEEDBACK_LEN) if read_current
                    else (p.FEEDBACK_NO_CURRENT_START, p.FEEDBACK_NO_CURRENT_LEN))
    leader.connect()
    try:
        for k in range(30):
            bank.q[: leader.n_joints] += 0.37 * (k % 3 - 1)  # moves of a third of a turn, both ways
            got = leader.bus.sync_read(leader._read_group, leader.read_ids, leader.rx_timeout_ms,
                                       leader.fast_read)
            assert len(got) == len(leader.read_ids)
            ref = _numpy_decode(leader, got)
            st_ = leader._state_all_fresh(got)
            for a, b in zip((st_.q, st_.q_dot, st_.current, st_.tau_m, leader._q_servo), ref, strict=True):
                assert _same(a, b)
    finally:
        leader.disconnect()
        emu.close()


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.integers(-2**15, 2**15 - 1), st.integers(-2**31, 2**31 - 1),
                          st.integers(-2**31, 2**31 - 1)), min_size=4, max_size=4),
       st.lists(st.integers(-2**31, 2**31 - 1), min_size=4, max_size=4))
def test_decode_of_any_field_values_is_the_numpy_decode(connected, blocks, ticks_prev):
    _, _, leader = connected
    got = {i: (p.le(c, 2) + p.le(v, 4) + p.le(x, 4), 0) for i, (c, v, x) in zip(leader.read_ids, blocks)}
    leader._ticks_prev = np.array(ticks_prev, np.int64)
    ref = _numpy_decode(leader, got)
    st_ = leader._state_all_fresh(got)
    for a, b in zip((st_.q, st_.q_dot, st_.current, st_.tau_m, leader._q_servo), ref, strict=True):
        assert _same(a, b)


@pytest.fixture(scope="module")
def connected():
    bank, emu, leader = make()
    leader.connect()
    yield bank, emu, leader
    leader.disconnect()
    emu.close()


@pytest.fixture(scope="module")
def trigger_leader():
    _, emu, leader = make(gripper=True)
    yield leader
    emu.close()


@settings(max_examples=200, deadline=None)
@given(st.floats(width=64), st.integers(-2**15, 2**15 - 1),
       st.sampled_from([(0.2, 1.2), (1.2, 0.2), (0.5, 0.5), (-2.0, 5.5), (0.0, -0.0)]), st.booleans())
def test_the_decodes_trigger_is_trigger(trigger_leader, q_trigger, units, open_closed, read_current):
    """_state_of's trigger written out (the usual tick) gives _trigger's values, bit for bit: any angle
    (NaN, +-inf, -0.0, past either end), any current, either direction, a zero span, with and without
    current."""
    leader, n = trigger_leader, trigger_leader.n_joints
    leader.config.gripper_open_rad, leader.config.gripper_closed_rad = open_closed
    leader.config.read_current = read_current
    ticks = tuple(range(100, 100 + n + 1))
    leader._q_servo, leader._ticks_prev = [0.0] * n + [q_trigger], ticks  # delta 0: the angle as given
    cur = tuple(range(n)) + (units,) if read_current else None
    st_ = leader._state_of(0.0, ticks, ticks, cur, None)
    pos, effort = leader._trigger(units)
    assert np.float64(st_.gripper_pos).tobytes() == np.float64(pos).tobytes()
    assert np.float64(st_.gripper_effort).tobytes() == np.float64(effort).tobytes()
