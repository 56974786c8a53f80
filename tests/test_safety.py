"""The safety layer: hypothesis tries arbitrary inputs (NaN, inf, huge) and no output leaves the limits."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from hardware.safety import (
    MAX_RATE_DT_S,
    DeviceHold,
    SafeFollowerCommand,
    SafeLeaderTorque,
    SafetyLayer,
    Watchdog,
    limit_position_target,
    limit_torque,
)
from hardware.types import FollowerCommand, JointLimits

N = 6
LIM = JointLimits(q_min=np.deg2rad([-150, 0, -170, -100, -70, -120]),
                  q_max=np.deg2rad([150, 180, 0, 100, 70, 120]),
                  v_max=np.full(N, 3.0), tau_max=np.array([8, 8, 8, 3, 3, 3.0]),
                  tau_rate_max=np.full(N, 200.0), kp_max=np.full(N, 100.0), kd_max=np.full(N, 5.0))
EPS = 1e-9

wild = st.floats(allow_nan=True, allow_infinity=True, width=64)
wild_vec = arrays(np.float64, N, elements=wild)
maybe_vec = st.one_of(st.none(), wild_vec, arrays(np.float64, st.integers(0, 9), elements=wild),
                      st.just("garbage"), st.lists(wild, max_size=8))
dts = st.one_of(st.floats(-1.0, 1.0), st.just(float("nan")), st.just(float("inf")))


def in_pos_limits(q):
    return np.all(np.isfinite(q)) and np.all(q >= LIM.q_min - EPS) and np.all(q <= LIM.q_max + EPS)


@settings(max_examples=300, deadline=None)
@given(q=wild_vec, q_prev_u=arrays(np.float64, N, elements=st.floats(0, 1)), dt=dts)
def test_position_target_never_leaves_limits(q, q_prev_u, dt):
    q_prev = LIM.q_min + q_prev_u * (LIM.q_max - LIM.q_min)
    out, _ = limit_position_target(q, q_prev, dt, LIM)
    assert in_pos_limits(out)
    assert np.all(np.abs(out - q_prev) <= LIM.v_max * MAX_RATE_DT_S + EPS)


@settings(max_examples=300, deadline=None)
@given(tau=wild_vec, prev_u=arrays(np.float64, N, elements=st.floats(-1, 1)), dt=dts)
def test_torque_never_leaves_limits_and_slews(tau, prev_u, dt):
    prev = prev_u * LIM.tau_max
    out, _ = limit_torque(tau, prev, dt, LIM)
    assert np.all(np.isfinite(out)) and np.all(np.abs(out) <= LIM.tau_max + EPS)
    d = float(np.clip(dt if np.isfinite(dt) else 0, 0, MAX_RATE_DT_S))
    grew = np.abs(out) > np.abs(prev) + EPS
    # magnitude only grows by the slew limit; it may fall to zero at once
    assert np.all(np.abs(out - prev)[grew] <= LIM.tau_rate_max[grew] * d + EPS)


@settings(max_examples=200, deadline=None)
@given(cmds=st.lists(st.tuples(maybe_vec, maybe_vec, maybe_vec, maybe_vec, st.floats(0, 0.2)),
                     min_size=1, max_size=12),
       q_meas=wild_vec)
def test_follower_sequences_stay_inside(cmds, q_meas):
    layer = SafetyLayer(LIM)
    t, prev_q = 0.0, None
    for q, tau, kp, kd, dt in cmds:
        t += dt
        out = layer.follower(FollowerCommand(q=q, tau_ff=tau, kp=kp, kd=kd), t, q_meas)
        assert in_pos_limits(out.q)
        assert np.all(np.abs(out.tau_ff) <= LIM.tau_max + EPS) and np.all(np.isfinite(out.tau_ff))
        if out.kp is not None:
            assert np.all((out.kp >= 0) & (out.kp <= LIM.kp_max))
            assert np.all((out.kd >= 0) & (out.kd <= LIM.kd_max))
        if prev_q is not None:
            assert np.all(np.abs(out.q - prev_q) <= LIM.v_max * min(dt, MAX_RATE_DT_S) + 1e-7)
        prev_q = out.q


@settings(max_examples=200, deadline=None)
@given(seq=st.lists(st.tuples(maybe_vec, st.floats(0, 0.2)), min_size=1, max_size=12))
def test_leader_sequences_stay_inside(seq):
    layer = SafetyLayer(LIM)
    t = 0.0
    for tau, dt in seq:
        t += dt
        out = layer.leader(tau, t)
        assert np.all(np.isfinite(out.tau)) and np.all(np.abs(out.tau) <= LIM.tau_max + EPS)


def test_hold_is_inside_limits_even_from_nan_state():
    layer = SafetyLayer(LIM)
    h = layer.follower_hold(0.0, np.full(N, np.nan), "test")
    assert h.hold and in_pos_limits(h.q) and np.all(h.kp == 0) and np.all(h.tau_ff == 0)
    assert layer.holds == 1 and layer.last_fault == "test"


def test_nan_target_keeps_previous_and_counts():
    layer = SafetyLayer(LIM)
    q0 = np.full(N, 0.0)
    q0[1], q0[2] = 1.0, -1.0
    first = layer.follower(FollowerCommand(q=q0), 0.0, q0)
    bad = q0.copy()
    bad[0] = np.nan
    out = layer.follower(FollowerCommand(q=bad), 0.002, q0)
    assert out.q[0] == first.q[0] and layer.rejected == 1


def test_safe_types_cannot_be_forged():
    with pytest.raises(TypeError):
        SafeLeaderTorque(tau=np.zeros(N), _token=object())
    with pytest.raises(TypeError):
        SafeFollowerCommand(q=np.zeros(N), tau_ff=np.zeros(N), kp=None, kd=None, gripper=None, hold=False,
                            _token=None)


def test_watchdog_expires_on_stale_commands_and_feedback():
    w = Watchdog(0.05)
    assert w.stale(10.0) is None  # nothing fed yet: not started, not stale
    w.feed_command(1.0)
    w.feed_feedback(1.0)
    assert w.stale(1.04) is None
    assert w.stale(1.06).kind is DeviceHold.NO_COMMAND and w.stale(1.06).get("ms") == pytest.approx(60.0)
    w.feed_command(1.06)
    assert w.stale(1.07).kind is DeviceHold.NO_FEEDBACK


def test_limits_validate():
    with pytest.raises(ValueError):
        JointLimits(q_min=np.zeros(2), q_max=np.zeros(2), v_max=np.ones(2), tau_max=np.ones(2),
                    tau_rate_max=np.ones(2))
    with pytest.raises(ValueError):
        JointLimits(q_min=-np.ones(2), q_max=np.ones(3), v_max=np.ones(2), tau_max=np.ones(2),
                    tau_rate_max=np.ones(2))
