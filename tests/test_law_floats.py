"""The leader law's float kernels (teleop/law_floats.py, feedback_torque_floats) against the numpy terms of
leader_law.py / feedback.py, bit for bit, on any floats: NaN, +-inf, -0.0 and ties (hypothesis); and the
whole LeaderLaw.step against the numpy sum it replaced."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from factr2_teleop.teleop.feedback import feedback_torque, feedback_torque_floats
from factr2_teleop.teleop.law_floats import (
    barrier_floats,
    friction_coulomb_floats,
    friction_dither_floats,
    law_tau_floats,
    scaled,
    sum_cap,
)
from factr2_teleop.teleop.leader_law import (
    LeaderInputs,
    LeaderLaw,
    LeaderLawConfig,
    cap_total,
    damping_term,
    friction_coulomb,
    friction_dither,
    gravity_term,
    joint_limit_barrier,
)
from hardware.types import JointLimits

N = 6
SPECIAL = st.sampled_from([0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, -1.0, 0.5, -0.5, 2.0])
ANY = st.one_of(SPECIAL, st.floats(allow_nan=True, allow_infinity=True, width=64))
VEC = st.lists(ANY, min_size=N, max_size=N)
NONNEG = st.lists(st.one_of(st.sampled_from([0.0, 0.5, 1.0, np.inf]), st.floats(0, 1e3)), min_size=N,
                  max_size=N)
SIGN = st.lists(st.sampled_from([1.0, -1.0]), min_size=N, max_size=N)


def _bits(a) -> bytes:
    return np.asarray(a, dtype=float).tobytes()


def _a(x) -> np.ndarray:
    return np.asarray(x, dtype=float)


@settings(max_examples=300, deadline=None)
@given(VEC, VEC, NONNEG, NONNEG, NONNEG, SIGN)
def test_friction_kernels_are_the_numpy_terms(g, qd, gain, mn, thr, sign):
    with np.errstate(all="ignore"):
        ref, _ = friction_dither(_a(g), _a(qd), _a(gain), _a(mn), _a(thr), _a(sign))
        ref_c = friction_coulomb(_a(qd), _a(gain), _a(thr))
    assert _bits(friction_dither_floats(g, qd, gain, mn, thr, sign)) == _bits(ref)
    assert _bits(friction_coulomb_floats(qd, gain, thr)) == _bits(ref_c)


@settings(max_examples=300, deadline=None)
@given(VEC, VEC, VEC, VEC, NONNEG, NONNEG, NONNEG)
def test_barrier_and_products_are_the_numpy_terms(q, qd, q_min, q_max, margin, kp, kd):
    with np.errstate(all="ignore"):
        ref = joint_limit_barrier(_a(q), _a(qd), _a(q_min), _a(q_max), _a(margin), _a(kp), _a(kd))
        lo, hi = (_a(q_min) + _a(margin)).tolist(), (_a(q_max) - _a(margin)).tolist()
        got = barrier_floats(q, qd, lo, hi, (-_a(kp)).tolist(), kd)
        assert _bits(np.zeros(N) if got is None else got) == _bits(ref)
        assert _bits(scaled((-_a(kd)).tolist(), qd)) == _bits(damping_term(_a(qd), _a(kd)))
        assert _bits(scaled(kp, q)) == _bits(gravity_term(_a(q), _a(kp)))


@settings(max_examples=300, deadline=None)
@given(st.lists(VEC, min_size=1, max_size=7), NONNEG)
def test_sum_and_cap_are_the_numpy_sum(terms, cap):
    cap = [c if c > 0 else 1.0 for c in cap]
    with np.errstate(all="ignore"):
        total = np.zeros(N)
        for t in terms:
            total += _a(t)
        total = np.where(np.isfinite(total), total, 0.0)
        ref, n = cap_total(total, _a(cap))
    got_total, got, m = sum_cap(terms, cap)
    assert _bits(got_total) == _bits(total) and _bits(got) == _bits(ref) and m == n


@settings(max_examples=400, deadline=None)
@given(VEC, VEC, VEC, VEC, VEC, VEC, NONNEG, NONNEG, NONNEG, NONNEG, SIGN,
       st.sampled_from(["dither", "coulomb", "off"]), st.booleans(), st.booleans(), st.booleans())
def test_one_pass_sum_is_the_terms_summed_and_capped(gl, qd, q, ns, fb, gain, dk, thr, cc, cap, sign, mode,
                                                     grav_on, barrier_on, ns_on):
    """law_tau_floats against the term kernels summed by sum_cap (each checked against numpy above)."""
    qd = [v if np.isfinite(v) else 0.0 for v in qd]  # LeaderLaw.step zeroes a non-finite q_dot first
    cap = [c if c > 0 else 1.0 for c in cap]
    f = {"dither_gain": dk, "dither_min": thr[::-1], "v_thr": thr, "coulomb": cc,
         "b_lo": [-1.0, -0.5, 0.0, -2.0, -np.inf, 0.3], "b_hi": [1.0, 0.5, 0.2, 2.0, np.inf, 0.4],
         "neg_b_kp": (-_a(dk)).tolist(), "b_kd": cc[::-1], "neg_damp": (-_a(cc)).tolist(), "cap": cap}
    zeros = [0.0] * N
    g0 = gl if grav_on else zeros
    fric = (friction_dither_floats(g0, qd, f["dither_gain"], f["dither_min"], f["v_thr"], sign)
            if mode == "dither" else friction_coulomb_floats(qd, f["coulomb"], f["v_thr"])
            if mode == "coulomb" else zeros)
    bar = barrier_floats(q, qd, f["b_lo"], f["b_hi"], f["neg_b_kp"], f["b_kd"]) if barrier_on else None
    terms = [scaled(gain, gl) if grav_on else zeros, fric, zeros if bar is None else bar,
             ns if ns_on else zeros, scaled(f["neg_damp"], qd), fb]
    _, ref, n = sum_cap(terms, cap)
    got, m = law_tau_floats(gl if grav_on else None, gain, qd, q if barrier_on else None, mode == "dither",
                            mode == "coulomb", sign, f, ns if ns_on else None, fb)
    assert _bits(got) == _bits(ref) and m == n


@settings(max_examples=300, deadline=None)
@given(VEC, NONNEG, st.one_of(st.sampled_from([0.0, -0.0, 1.0, 0.5]), st.floats(0, 1)), NONNEG)
def test_feedback_kernel_is_the_numpy_form(tau, gain, gate, clip):
    with np.errstate(all="ignore"):
        ref = feedback_torque(_a(tau), _a(gain), gate, _a(clip))
    assert _bits(feedback_torque_floats(tau, gain, gate, clip)) == _bits(ref)


def _numpy_step(law: LeaderLaw, inp: LeaderInputs, sign: np.ndarray) -> tuple[dict, np.ndarray, int]:
    """LeaderLaw.step as the numpy sum of the pure terms (the form the float path replaced), no feedback."""
    q, qd = _a(inp.q), _a(inp.q_dot)
    qd = np.where(np.isfinite(qd), qd, 0.0)
    g = law.gravity(q)
    terms = {"gravity": gravity_term(g, law.g_gain),
             "friction": friction_dither(g, qd, law.dither_gain, law.dither_min, law.v_thr, sign)[0],
             "barrier": joint_limit_barrier(q, qd, law.limits.q_min, law.limits.q_max, law.b_margin, law.b_kp,
                                            law.b_kd),
             "null_space": np.zeros(N), "damping": damping_term(qd, law.damp), "feedback": np.zeros(N)}
    total = np.zeros(N)
    for v in terms.values():
        total += v
    total = np.where(np.isfinite(total), total, 0.0)
    tau, capped = cap_total(total, law.cap)
    return terms, tau, capped


@settings(max_examples=200, deadline=None)
@given(VEC, VEC)
def test_step_is_the_numpy_sum_bit_for_bit(q, qd):
    lim = JointLimits(q_min=np.full(N, -2.0), q_max=np.full(N, 2.0), v_max=np.ones(N),
                      tau_max=np.full(N, 0.8), tau_rate_max=np.full(N, 50.0))
    cfg = LeaderLawConfig(damping_kd=[0.0, 0.01, 0.02, 0.0, 0.1, 0.0])
    law = LeaderLaw(cfg, lim, gravity_fn=lambda x: 0.3 * np.sin(np.asarray(x)) - 0.1)
    inp = LeaderInputs(t=0.0, q=_a(q), q_dot=_a(qd))
    with np.errstate(all="ignore"):
        for _ in range(2):  # the dither sign flips between ticks
            sign = np.asarray(law._dither_sign, dtype=float)
            terms, tau, capped = _numpy_step(law, inp, sign)
            out = law.step(inp, feedback_on=False)
            assert _bits(out.tau) == _bits(tau) and out.capped == capped
            assert list(out.terms) == list(terms)
            for k in terms:
                assert _bits(out.terms[k]) == _bits(terms[k]), k


@settings(max_examples=300, deadline=None)
@given(VEC, st.lists(st.floats(-10, 10), min_size=N, max_size=N), NONNEG,
       st.one_of(st.sampled_from([0.0, -0.0, 0.002, np.nan, np.inf]), st.floats(0, 1)))
def test_rate_limit_is_its_numpy_form(q, prev, v_max, dt):
    from factr2_teleop.teleop.soft_start import rate_limit

    q_a, p_a, v_a = _a(q), _a(prev), _a(v_max)
    with np.errstate(all="ignore"):
        x = np.where(np.isfinite(q_a), q_a, p_a)
        step = v_a * max(float(dt), 0.0)
        ref = np.minimum(np.maximum(x, p_a - step), p_a + step)
        assert _bits(rate_limit(q_a, p_a, v_a, dt)) == _bits(ref)
        assert _bits(rate_limit(q_a, p_a, 0.7, dt)) == _bits(
            np.minimum(np.maximum(x, p_a - 0.7 * max(float(dt), 0.0)), p_a + 0.7 * max(float(dt), 0.0)))
