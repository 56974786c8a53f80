"""Streaming estimator: equals the batch model exactly, NaN guard, OOD flag, EMA; carried state + audits."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from calibration.next.checkpoint import NextCheckpoint
from calibration.next.data import Normalizer, make_inputs
from calibration.next.estimator import (
    FLAG_NONFINITE,
    FLAG_OOD,
    FLAG_UNVERIFIED,
    FLAG_WARMUP,
    NextEstimator,
    batch_tau_f,
)
from calibration.next.model import ModelConfig, NextModel
from calibration.next.train import carried_state_diff

torch.set_num_threads(1)


def _ck(arch="lstm", history=12, n_j=3):
    torch.manual_seed(0)
    m = NextModel(ModelConfig(n_in=3 * n_j, n_out=n_j, history=history, arch=arch, hidden=24, head_hidden=32))
    m.eval()
    rng = np.random.default_rng(0)
    norm = Normalizer(rng.normal(size=3 * n_j), rng.uniform(0.5, 2, 3 * n_j), rng.normal(size=n_j),
                      rng.uniform(0.5, 2, n_j))
    return NextCheckpoint(model=m, normalizer=norm, arm="test", joint_names=[f"j{i}" for i in range(n_j)],
                          units="N*m", inputs="q,qd,dq", rate_hz=100.0, x_min=np.full(3 * n_j, -3.0),
                          x_max=np.full(3 * n_j, 3.0))


def _stream(n=80, n_j=3, seed=1):
    rng = np.random.default_rng(seed)
    q = np.cumsum(rng.normal(0, 0.05, (n, n_j)), 0)
    return q, rng.normal(0, 0.5, (n, n_j)), q + rng.normal(0, 0.01, (n, n_j)), rng.normal(size=(n, n_j))


@pytest.mark.parametrize("arch", ["lstm", "gru", "mlp"])
def test_streaming_equals_batch(arch):
    ck = _ck(arch)
    q, qd, qc, tau = _stream()
    ref = batch_tau_f(ck, q, qd, qc)
    est = NextEstimator(ck)
    outs = [est.update(q[i], qd[i], qc[i], tau[i]) for i in range(len(q))]
    for i, o in enumerate(outs):
        if i < ck.history - 1:
            assert o.flags & FLAG_WARMUP and np.all(np.isnan(o.tau_ext)) and not o.valid
        else:
            assert o.valid
            np.testing.assert_allclose(o.tau_f, ref[i], atol=1e-4)
            np.testing.assert_allclose(o.tau_ext, tau[i] - ref[i], atol=1e-4)


def test_nan_guard_never_raises_and_recovers():
    ck = _ck()
    q, qd, qc, tau = _stream()
    est = NextEstimator(ck)
    for i in range(20):
        est.update(q[i], qd[i], qc[i], tau[i])
    bad = q[20].copy()
    bad[1] = np.nan
    o = est.update(bad, qd[20], qc[20], tau[20])
    assert o.flags & FLAG_NONFINITE and np.all(np.isnan(o.tau_ext))
    o = est.update(q[21], qd[21], np.full(3, np.inf), tau[21])
    assert o.flags & FLAG_NONFINITE
    o = est.update(q[21], qd[21], qc[21], [np.nan, 0, 0])  # bad torque only: tau_f still computed
    assert o.flags & FLAG_NONFINITE and np.all(np.isnan(o.tau_ext))
    assert est.update([1.0], [2.0], [3.0], [4.0]).flags & FLAG_NONFINITE  # wrong size
    assert est.update("x", qd[0], qc[0], tau[0]).flags & FLAG_NONFINITE
    # after a restart the window fills again and the result matches the batch model on the new stretch
    est.reset()
    ref = batch_tau_f(ck, q[30:], qd[30:], qc[30:])
    outs = [est.update(q[i], qd[i], qc[i], tau[i]) for i in range(30, 80)]
    np.testing.assert_allclose(outs[-1].tau_f, ref[-1], atol=1e-4)


def test_ood_flag():
    ck = _ck()
    q, qd, qc, tau = _stream()
    est = NextEstimator(ck, ood_margin=0.1)
    assert not est.update(q[0], qd[0], qc[0], tau[0]).ood
    far = q[1].copy()
    far[0] = 10.0  # outside [-3, 3] widened by 10 %
    assert est.update(far, qd[1], far, tau[1]).flags & FLAG_OOD


def test_ema_smoothing():
    ck = _ck()
    q, qd, qc, tau = _stream()
    raw, ema = NextEstimator(ck), NextEstimator(ck, ema_alpha=0.2)
    a = np.array([raw.update(q[i], qd[i], qc[i], tau[i]).tau_ext for i in range(80)])[ck.history:]
    b = np.array([ema.update(q[i], qd[i], qc[i], tau[i]).tau_ext for i in range(80)])[ck.history:]
    assert np.abs(np.diff(b, axis=0)).mean() < np.abs(np.diff(a, axis=0)).mean()
    with pytest.raises(ValueError):
        NextEstimator(ck, ema_alpha=0.0)


@pytest.mark.parametrize("works", [0, 1, 3, 10])
def test_deferred_work_gives_the_same_estimates(works):
    """defer=True: update() steps only the run that completes (and the one that starts); work() calls in
    between step the rest -- any number of them, including none, must give the same numbers."""
    ck = _ck("lstm")
    q, qd, qc, tau = _stream(n=60)
    ref = batch_tau_f(ck, q, qd, qc)
    est = NextEstimator(ck, defer=True, parts=3)
    out = []
    for k in range(len(q)):
        out.append(est.update(q[k], qd[k], qc[k], tau[k]).tau_f)
        for _ in range(works):
            est.work()
    out = np.array(out)
    h = ck.model.cfg.history
    assert np.all(np.isnan(out[: h - 1]))
    assert np.allclose(out[h - 1:], ref[h - 1:], atol=1e-5)


def _long_memory(ck):
    """The same checkpoint with every forget gate saturated open: its cell state never forgets, so a carried
    run and a window run drift apart."""
    for layer in (0, 1):
        b = getattr(ck.model.rnn, f"bias_ih_l{layer}")
        h = b.shape[0] // 4
        with torch.no_grad():
            b[h:2 * h] = 30.0
    return ck


def _measured(ck, n=200):
    q, qd, qc, _ = _stream(n=n)
    x = torch.as_tensor(ck.normalizer.norm_x(make_inputs(q, qd, qc, ck.inputs)).astype(np.float32))
    return carried_state_diff(ck.model, x, np.arange(ck.history - 1, n), ck.history) * ck.normalizer.y_std


def test_carried_state_diff_tells_fading_from_long_memory():
    fading, long = _measured(_ck()), _measured(_long_memory(_ck()))
    assert np.all(fading < 1e-3)  # a freshly initialised LSTM forgets within H = 12 samples
    assert np.all(long > 20 * fading) and np.max(long) > 1e-2


def test_carried_mode_follows_the_window_model_and_audits_it():
    ck = _ck()
    ck.metrics = {"val_l1": [0.1] * 3, "carried_max_diff": list(_measured(ck))}
    q, qd, qc, tau = _stream(n=120, seed=3)
    ref = batch_tau_f(ck, q, qd, qc)
    est = NextEstimator(ck)
    assert est.mode == "carried"
    outs = [est.update(q[i], qd[i], qc[i], tau[i]) for i in range(len(q))]
    h = ck.history
    assert all(o.flags & FLAG_WARMUP for o in outs[:h - 1]) and all(o.valid for o in outs[h - 1:])
    np.testing.assert_allclose(np.array([o.tau_f for o in outs[h - 1:]]), ref[h - 1:], atol=2e-3)
    assert est.mode == "carried" and est.audits_done >= (len(q) - h) // (h // 2)
    assert np.all(est.audit_max_diff <= 1e-3) and not est.audit_failed


def test_failed_audit_switches_to_exact_windows_for_good():
    ck = _long_memory(_ck())
    q, qd, qc, tau = _stream(n=120, seed=4)
    ref = batch_tau_f(ck, q, qd, qc)
    est = NextEstimator(ck, carried=True, audit_tol=1e-4)
    outs = [est.update(q[i], qd[i], qc[i], tau[i]) for i in range(len(q))]
    assert est.audit_failed and est.mode == "exact"
    h = ck.history
    # the failing tick returns the audit's (exact) output; the exact windows' first comes H - 1 ticks later
    unverified = [i for i, o in enumerate(outs) if o.flags & FLAG_UNVERIFIED]
    assert len(unverified) == h - 2 and all(outs[i].valid for i in unverified)
    after = unverified[-1] + 1  # exact windows from here on, equal to the batch model
    np.testing.assert_allclose(np.array([o.tau_f for o in outs[after:]]), ref[after:], atol=1e-4)
    est.reset()
    assert est.mode == "exact"


def test_mode_choice():
    ck = _ck()
    assert NextEstimator(ck).mode == "exact"  # nothing measured: exact windows
    ck.metrics = {"val_l1": [0.1] * 3, "carried_max_diff": [1e-4, 1e-4, 5e-3]}  # one joint above 1 % of L1
    assert NextEstimator(ck).mode == "exact"
    ck.metrics["carried_max_diff"][2] = 1e-4
    assert NextEstimator(ck).mode == "carried"
    assert NextEstimator(ck, carried=False).mode == "exact"
    with pytest.raises(ValueError):
        NextEstimator(_ck(), carried=True)  # no validation L1 to set the audit's tolerance
    with pytest.raises(ValueError):
        NextEstimator(_ck("gru"), carried=True)
    assert NextEstimator(_ck("gru")).mode == "torch"
