"""The safety layer's float kernels (hardware/safety.py) against the numpy formulation they replaced, bit for
bit, on any floats: NaN, +-inf, -0.0 and ties included (hypothesis). Also small_vec.np_max / np_min /
clamp_floats against numpy's maximum / minimum."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.safety import _rate_dt, limit_position_floats, limit_torque_floats
from hardware.small_vec import clamp_floats, np_max, np_min

N = 6
SPECIAL = st.sampled_from([0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, -1.0, 0.5, -0.5])
ANY = st.one_of(SPECIAL, st.floats(allow_nan=True, allow_infinity=True, width=64))
VEC = st.lists(ANY, min_size=N, max_size=N)
POS = st.lists(st.one_of(st.sampled_from([0.5, 1.0, np.inf]),
                         st.floats(1e-6, 1e6)), min_size=N, max_size=N)
FIN = st.lists(st.one_of(st.sampled_from([0.0, -0.0, 1.0, -1.0]), st.floats(-10, 10)), min_size=N, max_size=N)
DT = st.one_of(st.sampled_from([0.0, -0.0, 0.002, np.nan, np.inf, -1.0]), st.floats(-1, 1))


def _bits(a) -> bytes:
    return np.asarray(a, dtype=float).tobytes()


def _ref_torque(raw, prev, dt, rate, tau_max):
    """The numpy form limit_torque had before its float kernel (hardware/safety.py)."""
    raw, prev, rate, tau_max = (np.asarray(x, dtype=float) for x in (raw, prev, rate, tau_max))
    t = np.where(np.isfinite(raw), raw, 0.0)
    with np.errstate(all="ignore"):
        r = rate * _rate_dt(dt)
        lo = np.maximum(np.minimum(prev - r, np.minimum(prev, 0.0)), -tau_max)
        hi = np.minimum(np.maximum(prev + r, np.maximum(prev, 0.0)), tau_max)
    out = np.minimum(np.maximum(t, lo), hi)
    return out, int(np.count_nonzero(out != raw))


def _ref_position(raw, prev, dt, v_max, q_min, q_max):
    raw, prev, v_max, q_min, q_max = (np.asarray(x, dtype=float) for x in (raw, prev, v_max, q_min, q_max))
    q = np.where(np.isfinite(raw), raw, prev)
    with np.errstate(all="ignore"):
        step = v_max * _rate_dt(dt)
        lo = np.maximum(prev - step, q_min)
        hi = np.minimum(prev + step, q_max)
    out = np.minimum(np.maximum(q, lo), hi)
    return out, int(np.count_nonzero(out != raw))


@settings(max_examples=400, deadline=None)
@given(VEC, VEC, DT, POS, POS)
def test_torque_kernel_is_the_numpy_form_bit_for_bit(raw, prev, dt, rate, tau_max):
    _check_torque(raw, prev, dt, rate, tau_max)


def _check_torque(raw, prev, dt, rate, tau_max):
    out, c = limit_torque_floats(raw, prev, _rate_dt(dt), rate, tau_max)
    ref, rc = _ref_torque(raw, prev, dt, rate, tau_max)
    assert _bits(out) == _bits(ref) and c == rc


@settings(max_examples=400, deadline=None)
@given(VEC, FIN, DT, POS, FIN, FIN)
def test_position_kernel_is_the_numpy_form_bit_for_bit(raw, prev, dt, v_max, a, b):
    _check_position(raw, prev, dt, v_max, a, b)


def _check_position(raw, prev, dt, v_max, a, b):
    q_min = np.minimum(a, b) - 1.0
    q_max = np.maximum(a, b) + 1.0
    prev = np.clip(prev, q_min, q_max)  # the layer keeps q_prev inside the limits
    out, c = limit_position_floats(raw, prev.tolist(), _rate_dt(dt), v_max, q_min.tolist(), q_max.tolist())
    ref, rc = _ref_position(raw, prev, dt, v_max, q_min, q_max)
    assert _bits(out) == _bits(ref) and c == rc


@settings(max_examples=300, deadline=None)
@given(VEC, VEC, VEC)
def test_np_max_min_and_clamp_are_numpys(x, lo, hi):
    assert _bits([np_max(a, b) for a, b in zip(x, lo)]) == _bits(np.maximum(x, lo))
    assert _bits([np_min(a, b) for a, b in zip(x, lo)]) == _bits(np.minimum(x, lo))
    assert _bits(clamp_floats(x, lo, hi)) == _bits(np.minimum(np.maximum(x, lo), hi))


def test_signed_zero_ties_follow_numpy():
    # numpy returns the second operand on a tie of 0.0 and -0.0
    assert np.signbit(np_max(0.0, -0.0)) and not np.signbit(np_max(-0.0, 0.0))
    assert np.signbit(np_min(0.0, -0.0)) and not np.signbit(np_min(-0.0, 0.0))
    out, _ = limit_torque_floats([-0.0] * N, [0.0] * N, 0.0, [1.0] * N, [1.0] * N)
    ref, _ = _ref_torque([-0.0] * N, [0.0] * N, 0.0, [1.0] * N, [1.0] * N)
    assert _bits(out) == _bits(ref)


@settings(max_examples=300, deadline=None)
@given(VEC, st.lists(st.sampled_from([1.0, -1.0]), min_size=N, max_size=N), POS, POS,
       st.lists(st.one_of(st.sampled_from([1750.0, 0.0]), st.floats(0, 1e5)), min_size=N, max_size=N))
def test_current_units_kernel_is_the_numpy_form(tau, signs, k, amps, limit):
    from hardware.dynamixel.leader_math import torque_to_current_ints, torque_to_current_units

    amps = [a if np.isfinite(a) else 1.0 for a in amps]
    with np.errstate(all="ignore"):
        ref = torque_to_current_units(tau, signs, k, amps, limit)
    assert torque_to_current_ints(tau, signs, k, amps, limit) == ref.tolist()


# every input finite: the kernels' fast path (no NaN tests); signed zeros, ties and values whose products or
# sums overflow included (an overflowing sum takes the general path, which must agree too)
FINITE = st.one_of(st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e308, -1e308, 5e-324]),
                   st.floats(allow_nan=False, allow_infinity=False, width=64))
FVEC = st.lists(FINITE, min_size=N, max_size=N)
FDT = st.one_of(st.sampled_from([0.0, -0.0, 0.002, 0.05]), st.floats(0, 1))


@settings(max_examples=500, deadline=None)
@given(FVEC, FVEC, FDT, FVEC, FVEC)
def test_torque_kernel_fast_path_is_the_numpy_form(raw, prev, dt, rate, tau_max):
    _check_torque(raw, prev, dt, [abs(x) for x in rate], [abs(x) for x in tau_max])


@settings(max_examples=500, deadline=None)
@given(FVEC, FIN, FDT, FVEC, FIN, FIN)
def test_position_kernel_fast_path_is_the_numpy_form(raw, prev, dt, v_max, a, b):
    _check_position(raw, prev, dt, [abs(x) for x in v_max], a, b)
