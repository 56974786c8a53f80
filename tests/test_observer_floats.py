"""The momentum observer's float step (calibration.baselines.momentum_observer_step_floats) against the numpy
step it replaced in the streaming estimator, bit for bit, on any floats (NaN, +-inf, -0.0 included); and the
streaming MomentumObserver against the batch baseline's arithmetic on a follower trajectory, bit for bit."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from calibration.baselines import momentum_observer_step, momentum_observer_step_floats
from calibration.estimators import EstimatorInput, MomentumObserver
from hardware.arms.dynamics import ArmDynamics
from hardware.types import JointState

N = 6
SPECIAL = st.sampled_from([0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, -1.0, 0.5, 1e-300, 1e300])
ANY = st.one_of(SPECIAL, st.floats(allow_nan=True, allow_infinity=True, width=64))
VEC = st.lists(ANY, min_size=N, max_size=N)


def _bits(a) -> bytes:
    return np.asarray(a, dtype=float).tobytes()


@settings(max_examples=400, deadline=None)
@given(VEC, VEC, VEC, VEC, VEC, VEC, VEC, ANY, VEC)
def test_float_step_is_the_numpy_step(integral, r, p, p0, tau_m, g, ctq, dt, k_o):
    a = [np.asarray(x, dtype=float) for x in (integral, r, p, p0, tau_m, g, ctq, k_o)]
    with np.errstate(all="ignore"):
        ref_i, ref_r = momentum_observer_step(a[0], a[1], a[2], a[3], a[4], a[5] - a[6], dt, a[7])
    got_i, got_r = momentum_observer_step_floats(integral, r, p, p0, tau_m, g, ctq, dt, k_o)
    assert _bits(got_i) == _bits(ref_i)
    assert _bits(got_r) == _bits(ref_r)


def _numpy_observer(dyn: ArmDynamics, samples, k_o: float) -> list[np.ndarray]:
    """The streaming observer's numpy arithmetic as it was before the float step (the reference)."""
    out, integral, r, p0, t_prev = [], np.zeros(N), np.zeros(N), None, None
    k = np.full(N, k_o)
    for t, q, qd, tau_m in samples:
        if p0 is None:
            p0, t_prev = dyn.mass_matrix(q) @ qd, t
            out.append(-r)
            continue
        beta = dyn.gravity(q) - dyn.coriolis_matrix(q, qd).T @ qd
        p = dyn.mass_matrix(q) @ qd
        integral, r = momentum_observer_step(integral, r, p, p0, tau_m, beta, t - t_prev, k)
        t_prev = t
        out.append(-r)
    return out


def test_streaming_observer_is_bit_for_bit_the_numpy_observer():
    rng = np.random.default_rng(3)
    samples = []
    for k in range(200):
        q = 0.5 * np.sin(0.01 * k + np.arange(N)) + 0.01 * rng.standard_normal(N)
        qd = np.cos(0.01 * k + np.arange(N)) + 0.01 * rng.standard_normal(N)
        samples.append((0.005 * k, q, qd, rng.standard_normal(N)))
    ref = _numpy_observer(ArmDynamics("piper"), samples, 50.0)
    obs = MomentumObserver.from_arm("piper", k_o=50.0)
    nan = np.full(N, np.nan)
    for (t, q, qd, tau_m), want in zip(samples, ref, strict=True):
        st_ = JointState(t=t, q=q, q_dot=qd, tau_m=tau_m, current=nan, q_cmd=nan, temperature=nan,
                         status=np.zeros(N, np.uint32))
        est = obs.update(EstimatorInput(t=t, follower=st_, q_leader_f=q, q_target_f=q))
        assert _bits(est.tau_ext) == _bits(want)
        again = obs.update(EstimatorInput(t=t, follower=st_, q_leader_f=q, q_target_f=q))  # no new sample
        assert _bits(again.tau_ext) == _bits(want) and again.t == t
