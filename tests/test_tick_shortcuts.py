"""The 500 Hz kernels' shortcuts (issue #53) against the forms they shortcut, bit for bit (hypothesis): a
value strictly inside its bounds passes unchanged, so the safety layer's torque and position limits, the
coupled rate limit, the feedback clip, the goal current's clip and the law's cap skip their clamps for it;
values on a bound, just past it, NaN, +-inf and -0.0 are generated around each bound to check the edge.
Also the Piper joint targets in one pack, the identity joint map without its product, and all_finite by
the sum."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from factr2_teleop.teleop.feedback import feedback_torque, feedback_torque_floats
from factr2_teleop.teleop.law_floats import friction_dither_floats, law_tau_floats, scaled, sum_cap
from factr2_teleop.teleop.mapping import JointMap, JointMapConfig
from factr2_teleop.teleop.soft_start import rate_limit_floats
from hardware.dynamixel.leader_math import torque_to_current_ints, torque_to_current_units
from hardware.piper import protocol as P
from hardware.safety import _rate_dt, limit_position_floats, limit_torque_floats
from hardware.small_vec import all_finite
from tests.test_safety_floats import _ref_position, _ref_torque

N = 6
EDGE = st.sampled_from([0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, -1.0])
FIN = st.floats(-10, 10)
# a fraction of the way from a centre to a bound: inside (|f| < 1), on it (+-1), just past it, far past it
FRAC = st.one_of(st.sampled_from([0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 1.0 + 2**-52, -1.0 - 2**-52, 2.0, -3.0]),
                 st.floats(-1.5, 1.5))


def _bits(a) -> bytes:
    return np.asarray(a, dtype=float).tobytes()


def _near(centre: float, half: float, f: float, edge: float | None) -> float:
    """centre + f * half, or an edge value (NaN, inf, a signed zero) when one is drawn."""
    return edge if edge is not None else centre + f * half


VALUES = st.lists(st.tuples(FIN, st.one_of(st.floats(0, 5), st.sampled_from([0.0, np.inf])), FRAC,
                            st.one_of(st.none(), EDGE)), min_size=N, max_size=N)


@settings(max_examples=500, deadline=None)
@given(VALUES, st.lists(st.one_of(st.floats(0.1, 20), st.sampled_from([np.inf, 1.0])), min_size=N,
                        max_size=N), st.sampled_from([0.0, -0.0, 0.002, 0.05, np.nan]))
def test_torque_limit_shortcut_is_the_numpy_form(vals, tau_max, dt):
    prev = [p for p, _, _, _ in vals]
    rate = [r / 0.002 for _, r, _, _ in vals]
    raw = [_near(p, r * min(_rate_dt(dt) / 0.002, 1.0), f, e) for p, r, f, e in vals]
    out, c = limit_torque_floats(raw, prev, _rate_dt(dt), rate, tau_max)
    ref, rc = _ref_torque(raw, prev, dt, rate, tau_max)
    assert _bits(out) == _bits(ref) and c == rc
    on_bound = [m * f for m, (_, _, f, _) in zip(tau_max, vals, strict=True)]  # around +-tau_max too
    out, c = limit_torque_floats(on_bound, prev, _rate_dt(dt), rate, tau_max)
    ref, rc = _ref_torque(on_bound, prev, dt, rate, tau_max)
    assert _bits(out) == _bits(ref) and c == rc


@settings(max_examples=500, deadline=None)
@given(VALUES, st.lists(st.floats(0.5, 3), min_size=N, max_size=N),
       st.sampled_from([0.0, -0.0, 0.002, 0.05, np.nan]), st.booleans())
def test_position_limit_shortcut_is_the_numpy_form(vals, span, dt, at_limits):
    prev = [p for p, _, _, _ in vals]
    q_min = [p - s for p, s in zip(prev, span, strict=True)]
    q_max = [p + s for p, s in zip(prev, span, strict=True)]
    v_max = [r / 0.002 if r > 0 else 1.0 for _, r, _, _ in vals]
    if at_limits:  # targets around the joint limits instead of the step
        raw = [_near(p, s, f, e) for p, s, (_, _, f, e) in zip(prev, span, vals, strict=True)]
    else:
        raw = [_near(p, v * _rate_dt(dt), f, e) for p, v, (_, _, f, e) in zip(prev, v_max, vals, strict=True)]
    out, c = limit_position_floats(raw, prev, _rate_dt(dt), v_max, q_min, q_max)
    ref, rc = _ref_position(raw, prev, dt, v_max, q_min, q_max)
    assert _bits(out) == _bits(ref) and c == rc


@settings(max_examples=400, deadline=None)
@given(VALUES, st.sampled_from([0.0, -0.0, 0.002, np.nan, np.inf]))
def test_rate_limit_shortcut_is_the_numpy_form(vals, dt):
    prev = [p for p, _, _, _ in vals]
    v = [r for _, r, _, _ in vals]
    q = [_near(p, r * dt if math.isfinite(r * dt) else 1.0, f, e) for p, r, f, e in vals]
    p_a, v_a, q_a = (np.asarray(x, dtype=float) for x in (prev, v, q))
    with np.errstate(all="ignore"):
        x = np.where(np.isfinite(q_a), q_a, p_a)
        step = v_a * dt
        ref = np.minimum(np.maximum(x, p_a - step), p_a + step)
    assert _bits(rate_limit_floats(q, prev, v, dt)) == _bits(ref)


@settings(max_examples=400, deadline=None)
@given(st.lists(st.tuples(st.one_of(st.floats(0.01, 10), st.sampled_from([0.0, np.inf])), FRAC,
                          st.one_of(st.none(), EDGE)), min_size=N, max_size=N),
       st.sampled_from([0.0, -0.0, 0.5, 1.0]))
def test_feedback_clip_shortcut_is_the_numpy_form(vals, gate):
    clip = [c for c, _, _ in vals]
    gain = [1.0] * N
    m = -gate if gate else -1.0
    tau = [e if e is not None else (c * f / m if math.isfinite(c) else f) for c, f, e in vals]
    with np.errstate(all="ignore"):
        ref = feedback_torque(np.asarray(tau), np.asarray(gain), gate, np.asarray(clip))
    assert _bits(feedback_torque_floats(tau, gain, gate, clip)) == _bits(ref)


@settings(max_examples=400, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([1.0, -1.0]), st.floats(0.1, 2),
                          st.one_of(st.sampled_from([1750.0, 0.0]), st.floats(0, 1e4)),
                          FRAC, st.one_of(st.none(), EDGE)), min_size=N, max_size=N))
def test_goal_current_clip_shortcut_is_the_numpy_form(vals):
    signs = [s for s, _, _, _, _ in vals]
    k = [x for _, x, _, _, _ in vals]
    amps = [0.00269] * N
    limit = [lim for _, _, lim, _, _ in vals]
    # torques whose units land around +-limit (and on it: ties round half to even either way)
    tau = [e if e is not None else s * f * lim * kk * 0.00269 for s, kk, lim, f, e in vals]
    with np.errstate(all="ignore"):
        ref = torque_to_current_units(tau, signs, k, amps, limit)
    assert torque_to_current_ints(tau, signs, k, amps, limit) == ref.tolist()


@settings(max_examples=400, deadline=None)
@given(st.lists(st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(0.1, 3), FRAC,
                          st.one_of(st.none(), EDGE)), min_size=N, max_size=N), st.booleans())
def test_law_cap_shortcut_is_the_terms_summed_and_capped(vals, dither):
    """law_tau_floats with sums around the cap (the shortcut's edge) against the terms summed by sum_cap."""
    gl = [g for g, _, _, _, _ in vals]
    qd = [v for _, v, _, _, _ in vals]
    cap = [c for _, _, c, _, _ in vals]
    # the feedback term puts the sum near f * cap (or on an edge value)
    fb = [e if e is not None else f * c - (g - v) for g, v, c, f, e in vals]
    zeros = [0.0] * N
    f = {"dither_gain": [0.1] * N, "dither_min": [0.05] * N, "v_thr": [0.5] * N, "coulomb": [0.0] * N,
         "b_lo": [-10.0] * N, "b_hi": [10.0] * N, "neg_b_kp": [-1.0] * N, "b_kd": [0.1] * N,
         "neg_damp": [-1.0] * N, "cap": cap}
    sign = [1.0, -1.0] * (N // 2)
    fric = friction_dither_floats(gl, qd, f["dither_gain"], f["dither_min"], f["v_thr"], sign) if dither \
        else zeros
    terms = [scaled([1.0] * N, gl), fric, zeros, zeros, scaled(f["neg_damp"], qd), fb]
    _, ref, n = sum_cap(terms, cap)
    got, m = law_tau_floats(gl, [1.0] * N, qd, None, dither, False, sign, f, None, fb)
    assert _bits(got) == _bits(ref) and m == n


def _targets_ref(q) -> tuple[bytes, bytes, bytes]:
    """encode_joint_targets as one _i32 and one ">ii" pack per frame (the form it replaced)."""
    m = [P._i32(float(x) * P.MDEG_PER_RAD) for x in q]
    return P._S_II.pack(m[0], m[1]), P._S_II.pack(m[2], m[3]), P._S_II.pack(m[4], m[5])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.sampled_from([0.0, -0.0, 1e9, -1e9, 37.48, -37.49]),
                          st.floats(-1e8, 1e8)), min_size=N, max_size=N))
def test_joint_targets_in_one_pack_are_the_frames_packed_one_by_one(q):
    assert P.encode_joint_targets(np.asarray(q)) == _targets_ref(q)  # an array (its tolist) and a list
    assert P.encode_joint_targets(q) == _targets_ref(q)


ANY = st.one_of(EDGE, st.floats(allow_nan=True, allow_infinity=True, width=64))


@settings(max_examples=300, deadline=None)
@given(st.lists(ANY, min_size=N, max_size=N), st.lists(st.one_of(st.sampled_from([0.0, -0.0]), FIN),
                                                       min_size=N, max_size=N))
def test_identity_map_is_the_product_bit_for_bit(x, offset):
    m = JointMap(JointMapConfig(offset_rad=offset), N, N)
    k, off = np.ones(N), np.asarray(offset, dtype=float)
    a = np.asarray(x, dtype=float)
    with np.errstate(all="ignore"):
        assert _bits(m.forward(a)) == _bits(k * a + off)
        got = m.torque_back(a)
        assert _bits(got) == _bits(k * a) and got is not a
        assert _bits(m.torque_back(2.5)) == _bits(k * 2.5)  # a value that broadcasts: as the product does


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(ANY, st.sampled_from([1e308, -1e308])), min_size=0, max_size=8))
def test_all_finite_by_the_sum_is_numpys(x):
    assert all_finite(np.asarray(x, dtype=float)) == bool(np.isfinite(np.asarray(x, dtype=float)).all())


RATES = st.lists(st.one_of(st.floats(0.01, 10), st.sampled_from([np.inf, 1.0])), min_size=N, max_size=N)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.one_of(ANY, FIN), FIN), min_size=N, max_size=N),
       st.one_of(EDGE, st.floats(0, 1)), RATES)
def test_coupled_step_is_rate_limit(qp, dt, rate):
    from factr2_teleop.teleop.soft_start import SoftStart, SoftStartConfig, rate_limit

    soft = SoftStart(SoftStartConfig(rate_limit_rad_s=rate), N, 0.002)
    q, prev = np.asarray([a for a, _ in qp]), np.asarray([b for _, b in qp])
    for _ in range(2):  # the rate's floats made, then kept
        assert _bits(soft.coupled_step(q, prev, dt)) == _bits(rate_limit(q, prev, soft.rate, dt))


TIMES = st.one_of(EDGE, st.floats(-1, 1), st.sampled_from([0.05, -0.05, 0.0500001]))


@settings(max_examples=300, deadline=None)
@given(TIMES, TIMES, TIMES)
def test_watchdog_fresh_shortcut_is_the_whole_check(now, t_cmd, t_fb):
    from hardware.safety import DeviceHold, Watchdog

    w = Watchdog(0.05)
    w.last_command_t, w.last_feedback_t = t_cmd, t_fb
    want = None  # the check written out: a fed time (finite) older than the timeout is stale
    if math.isfinite(t_cmd) and now - t_cmd > 0.05:
        want = DeviceHold.NO_COMMAND
    elif math.isfinite(t_fb) and now - t_fb > 0.05:
        want = DeviceHold.NO_FEEDBACK
    got = w.stale(now)
    assert (got is None) == (want is None) and (got is None or got.kind is want)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.one_of(ANY, FIN), FIN), min_size=N, max_size=N),
       st.lists(st.one_of(EDGE, st.floats(-0.01, 0.01)), min_size=3, max_size=3), RATES)
def test_coupled_step_from_its_own_last_target_is_rate_limit(qp, moves, rate):
    """coupled_step's q_prev its own last target (the coupled tick: the floats it kept with it) and the
    usual tick's copy of q_goal give rate_limit's values, bit for bit, tick after tick."""
    from factr2_teleop.teleop.soft_start import SoftStart, SoftStartConfig, rate_limit

    soft = SoftStart(SoftStartConfig(rate_limit_rad_s=rate), N, 0.002)
    q, prev = np.asarray([a for a, _ in qp]), np.asarray([b for _, b in qp])
    for m in moves:
        want = rate_limit(q, prev, soft.rate, 0.002)
        got = soft.coupled_step(q, prev, 0.002)
        assert _bits(got) == _bits(want) and got is not q and not got.flags.writeable
        prev, q = got, q + m  # the next tick starts from this target


@settings(max_examples=100, deadline=None)
@given(st.lists(st.one_of(st.floats(-7, 7), st.sampled_from([0.0, -0.0, 3.14159])), min_size=N, max_size=N))
def test_law_gravity_floats_are_gravity_tolist(q):
    """LeaderLaw.gravity_floats (pinocchio's result's floats, no copies) is gravity(q).tolist(), bit for bit,
    with the description's ArmDynamics.gravity; any other g(q) takes gravity() itself."""
    from factr2_teleop.teleop.leader_law import LeaderLaw, LeaderLawConfig, arm_model_fns

    grav, jac = arm_model_fns("gello_piper")
    law = LeaderLaw(LeaderLawConfig(), _limits(), grav, jac)
    qa = np.asarray(q)
    assert _bits(law.gravity_floats(qa)) == _bits(law.gravity(qa).tolist())
    assert law._g_floats[1] is not None  # the fast form was taken
    law.gravity_fn = lambda x: grav(x) * 2.0  # set again: its own result
    assert _bits(law.gravity_floats(qa)) == _bits((grav(qa) * 2.0).tolist())


def _limits():
    from hardware.types import JointLimits

    return JointLimits(q_min=np.full(N, -3.0), q_max=np.full(N, 3.0), v_max=np.full(N, 3.0),
                       tau_max=np.full(N, 1.0), tau_rate_max=np.full(N, 50.0))


@settings(max_examples=150, deadline=None)
@given(st.sampled_from(["coupled", "hold", "soft_start", "fault"]), st.booleans(), st.booleans(),
       st.booleans(), st.booleans(), st.sampled_from([None, 0.01, np.nan]), st.booleans())
def test_tick_record_by_position_is_the_keyword_record(phase, est_on, est_list, sent_on, out_on, grip, off):
    """ArmPair._record's positional TickRecord has the fields the keyword form gave, value for value."""
    import dataclasses
    from types import SimpleNamespace as NS

    from factr2_teleop.teleop.pair import FAULT, HOLD, STOPPED, ArmPair
    from factr2_teleop.teleop.record import TickRecord

    tau_e = [0.5] * N if est_list else np.arange(N, dtype=float)
    me = NS(follower=NS(n_joints=N), estimate=NS(tau_ext=tau_e) if est_on else None, phase=phase,
            sent=NS(q=np.ones(N), gripper=grip, hold=np.bool_(True)) if sent_on else None,
            cfg=NS(name="arm"), _offset=np.zeros(N) if off else None)
    out = NS(terms={"gravity": np.ones(N)}, gate=0.25, contact=np.bool_(True), fresh=1, gripper_tau=0.5)
    out = out if out_on else None
    ls, fs, tau = object(), object(), np.zeros(N)
    got = ArmPair._record(me, 1.5, ls, fs, tau, out)
    est, sent, nf = me.estimate, me.sent, N
    want = TickRecord(  # the keyword form
        t=1.5, pair="arm", phase=phase, leader=ls, follower=fs, leader_tau_cmd=tau,
        tau_ext=np.asarray(est.tau_ext, dtype=float) if est is not None else np.full(nf, np.nan),
        action_q=sent.q if sent is not None else np.full(nf, np.nan),
        action_gripper=float("nan") if sent is None or sent.gripper is None else float(sent.gripper),
        action_hold=bool(sent.hold) if sent is not None else phase in (HOLD, FAULT, STOPPED),
        leader_tau_terms=out.terms if out is not None else {}, gate=out.gate if out else 0.0,
        contact=bool(out.contact) if out else False, fresh=bool(out.fresh) if out else False,
        leader_gripper_tau_fb=out.gripper_tau if out else 0.0, perturb_q=me._offset)
    for f in dataclasses.fields(TickRecord):
        a, b = getattr(got, f.name), getattr(want, f.name)
        assert type(a) is type(b), f.name
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), f.name
        elif isinstance(a, float) and math.isnan(a):
            assert math.isnan(b), f.name
        else:
            assert a is b or a == b, f.name
    if est_on and not est_list:
        assert got.tau_ext is est.tau_ext  # a float64 array as it is, as np.asarray gives it
