"""Baselines on pinocchio's sample manipulator with synthetic data (exact trajectories, known torques)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calibration import baselines


@pytest.fixture(scope="module")
def motion():
    model = pin.buildSampleModelManipulator()
    dt, n = 0.001, 2000
    t = np.arange(n) * dt
    w, ph = 2 * np.pi * 0.5, np.arange(6)
    q = 0.5 * np.sin(w * t[:, None] + ph)
    qd = 0.5 * w * np.cos(w * t[:, None] + ph)
    qdd = -0.5 * w * w * np.sin(w * t[:, None] + ph)
    tau_f = baselines.rigid_body_torque(model, q, qd, qdd)
    return model, t, q, qd, qdd, tau_f


def test_rigid_body_torque_matches_m_c_g(motion):
    model, t, q, qd, qdd, tau_f = motion
    data = model.createData()
    k = 123
    m = pin.crba(model, data, q[k])
    m = np.triu(m) + np.triu(m, 1).T
    c = pin.computeCoriolisMatrix(model, data, q[k], qd[k])
    g = pin.computeGeneralizedGravity(model, data, q[k])
    np.testing.assert_allclose(tau_f[k], m @ qdd[k] + c @ qd[k] + g, atol=1e-9)


def test_zero_external_torque_gives_small_residual(motion):
    model, t, q, qd, qdd, tau_f = motion
    scale = np.abs(tau_f).mean()
    filic = baselines.filic_residual(model, t, q, qd, tau_f, accel_cutoff_hz=100.0, zero_phase=True)
    obs = baselines.momentum_observer(model, t, q, qd, tau_f, gain=50.0)
    assert np.abs(filic[50:-50]).mean() < 0.02 * scale
    assert np.abs(obs[50:]).mean() < 0.03 * scale


def test_known_external_torque_recovered(motion):
    model, t, q, qd, qdd, tau_f = motion
    ext = np.zeros_like(tau_f)
    ext[1000:, 1] = 2.0  # the motors spend 2 N*m more on joint 2 (tau_ext = tau_m - tau_f)
    tau_m = tau_f + ext
    obs = baselines.momentum_observer(model, t, q, qd, tau_m, gain=50.0)
    filic = baselines.filic_residual(model, t, q, qd, tau_m, accel_cutoff_hz=100.0, zero_phase=True)
    late = slice(1300, 1900)  # 5 observer time constants after the step
    assert np.abs(obs[late, 1] - 2.0).max() < 0.25
    assert np.abs(filic[late, 1] - 2.0).max() < 0.25
    assert np.abs(obs[late, [0, 2, 3, 4, 5]]).max() < 0.3
    # the observer is a first-order filter: about 63 % of the step after 1/K_o = 20 ms
    assert 0.9 < obs[1020, 1] < 1.6


def test_raw_and_ridge():
    rng = np.random.default_rng(0)
    n = 3000
    q = rng.uniform(-2, 2, (n, 2))
    qd = rng.normal(0, 1, (n, 2))
    qc = q + 0.01 * rng.normal(size=(n, 2))
    tau = 3 * np.sin(q) + 0.5 * qd + 0.2 * np.tanh(qd / 0.05) + 5 * (qc - q)
    np.testing.assert_array_equal(baselines.raw_torque(tau), tau)
    ridge = baselines.fit_ridge(q, qd, qc, tau, alpha=1e-8)
    assert np.abs(baselines.ridge_residual(ridge, q, qd, qc, tau)).max() < 1e-3


def test_lowpass_causal_and_zero_phase():
    t = np.arange(1000) * 0.001
    x = np.sin(2 * np.pi * 2 * t)[:, None]
    causal = baselines.lowpass(x, t, 50.0)
    zp = baselines.lowpass(x, t, 50.0, zero_phase=True)
    assert np.abs(zp - x)[100:-100].max() < np.abs(causal - x)[100:-100].max()
    np.testing.assert_array_equal(baselines.lowpass(x, t, 0.0), x)
