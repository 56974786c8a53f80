"""NEXT's physics prior: the identified fit recovers a mis-described arm (a payload, friction with break-away,
a torque constant that drifts with temperature, a ripple whose period nobody declared), filtering both sides
alike removes the acceleration filter's lag, streaming equals batch, the checkpoint carries it, and calibrate
trains on top of it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
import torch

from calibration.next.checkpoint import NextCheckpoint, load_checkpoint, save_checkpoint
from calibration.next.data import Normalizer
from calibration.next.estimator import FLAG_NO_TEMPERATURE, FLAG_NONFINITE, NextEstimator, batch_tau_f
from calibration.next.model import ModelConfig, NextModel
from calibration.next.prior import (
    Prior,
    PriorStream,
    description_prior,
    fit_prior,
    pinocchio_model,
    prior_torque,
)

torch.set_num_threads(1)
RATE = 100.0


def _motion(seconds=60.0, seed=0):
    """Smooth multi-sine motion of the Piper within its limits: t [s], q [rad], qd [rad/s], qdd [rad/s^2]."""
    from hardware.arms import load_arm

    lim = load_arm("piper").limits
    t = np.arange(int(seconds * RATE)) / RATE
    rng = np.random.default_rng(seed)
    mid, amp = (lim.q_min + lim.q_max) / 2, 0.25 * (lim.q_max - lim.q_min)
    q, qd, qdd = (np.zeros((len(t), 6)) for _ in range(3))
    for f, ph in zip(rng.uniform(0.05, 0.4, (3, 6)), rng.uniform(0, 6, (3, 6))):
        w = 2 * np.pi * f
        q += amp / 3 * np.sin(w * t[:, None] + ph)
        qd += amp / 3 * w * np.cos(w * t[:, None] + ph)
        qdd -= amp / 3 * w ** 2 * np.sin(w * t[:, None] + ph)
    return t, mid + q, qd, qdd


def _true_arm_torque(q, qd, qdd, coulomb, viscous, extra_mass_kg, stribeck=0.0, ripple=None, temp=None):
    """The 'real' arm: the description with a payload on the last link that nobody declared, friction
    (Coulomb + viscous + Stribeck break-away), optionally ripple (amp [N*m], cycles/rev) on every joint and a
    torque constant that falls 0.1 %/K as the motors heat (the drive reports torque from current, so the
    reported torque rises by as much)."""
    from hardware.sim.example_effects import with_payload

    m = with_payload(pinocchio_model("piper"), extra_mass_kg, [0.0, 0.0, 0.05], 1e-4)
    d = m.createData()
    rb = np.stack([pin.rnea(m, d, q[k], qd[k], qdd[k]) for k in range(len(q))])
    tau = rb + (coulomb + stribeck * np.exp(-(qd / 0.05) ** 2)) * np.tanh(qd / 0.005) + viscous * qd
    if ripple is not None:
        tau = tau + ripple[0] * np.sin(ripple[1] * q + 0.4)
    if temp is not None:
        tau = tau / (1.0 - 0.001 * (temp - 25.0))
    return tau


def test_identified_prior_recovers_an_undeclared_payload_and_friction():
    t, q, qd, qdd = _motion(90.0)
    coulomb = np.array([0.4, 0.5, 0.3, 0.1, 0.12, 0.08])
    viscous = np.array([0.2, 0.1, 0.15, 0.05, 0.03, 0.02])
    tau = _true_arm_torque(q, qd, qdd, coulomb, viscous, extra_mass_kg=0.3)
    p = fit_prior("identified", "piper", [(t, q, qd, tau)])
    t2, q2, qd2, qdd2 = _motion(30.0, seed=5)  # other motion: generalisation, not memory
    tau2 = _true_arm_torque(q2, qd2, qdd2, coulomb, viscous, extra_mass_kg=0.3)
    err_id = np.abs(tau2 - prior_torque(p, t2, q2, qd2, tau2))[20:].mean(0)
    err_desc = np.abs(tau2 - prior_torque(description_prior("piper"), t2, q2, qd2, tau2))[20:].mean(0)
    assert err_id.mean() < 0.25 * err_desc.mean(), (err_id, err_desc)
    coulomb_total = p.joint["coulomb"] + p.joint["coulomb_sharp"]  # the two signs share the Coulomb level
    np.testing.assert_allclose(coulomb_total, coulomb, atol=0.05)
    assert np.all(p.ripple_period == 0), p.ripple_period  # no ripple in these data: none is invented
    assert not p.uses_temperature  # no temperature logged: no temperature term


def test_identified_prior_finds_ripple_break_away_and_thermal_drift_nobody_declared():
    t, q, qd, qdd = _motion(120.0)
    coulomb, viscous, stribeck = np.full(6, 0.3), np.full(6, 0.1), np.full(6, 0.15)
    ripple = (np.array([0.06, 0.06, 0.06, 0.02, 0.02, 0.02]), np.array([36, 36, 36, 25, 25, 25.0]))
    heating = np.r_[0.0, np.linspace(0.3, 1.0, 5)]  # J1 stays at 25 degC: its drift is not identifiable
    temp = 25.0 + 30.0 * (1 - np.exp(-t / 60.0))[:, None] * heating  # heating up [degC]
    tau = _true_arm_torque(q, qd, qdd, coulomb, viscous, 0.3, stribeck, ripple, temp)
    p = fit_prior("identified", "piper", [(t, q, qd, tau, temp)])
    np.testing.assert_allclose(2 * np.pi / p.ripple_period, ripple[1], rtol=0.01)  # periods found
    np.testing.assert_allclose(np.hypot(p.joint["ripple_sin"], p.joint["ripple_cos"]), ripple[0], atol=0.01)
    np.testing.assert_allclose(p.joint["kt_temp"][1:3], 0.001, atol=0.0003)  # the joints that carry load
    assert np.isnan(p.temp_ref[0]) and p.joint["kt_temp"][0] == 0.0 and np.all(np.isfinite(p.temp_ref[1:]))
    assert np.all(p.joint["stribeck"] > 0.08), p.joint["stribeck"]
    t2, q2, qd2, qdd2 = _motion(30.0, seed=5)
    temp2 = np.full_like(q2, 60.0)  # hotter than anything in the calibration
    tau2 = _true_arm_torque(q2, qd2, qdd2, coulomb, viscous, 0.3, stribeck, ripple, temp2)
    err = np.abs(tau2 - prior_torque(p, t2, q2, qd2, tau2, temp2))[20:].mean()
    err_no_temp = np.abs(tau2 - prior_torque(p, t2, q2, qd2, tau2, None))[20:].mean()
    assert err < 0.03 and err < 0.5 * err_no_temp, (err, err_no_temp)


def test_filtering_both_sides_removes_the_acceleration_filters_lag():
    """The prior filters the residual (measured minus predicted torque, both at the same midpoint); FILIC
    filters only the acceleration, and keeps M(q) (qdd - qdd_filtered) in its residual. Same exact model,
    fast motion: the prior's error is far smaller."""
    from calibration.baselines import filic_residual

    t, q, qd, qdd = _motion(20.0)
    fast = 3.0  # three times faster: larger jerk
    t = t / fast
    qd, qdd = qd * fast, qdd * fast ** 2
    m = pinocchio_model("piper")
    d = m.createData()
    tau = np.stack([pin.rnea(m, d, q[k], qd[k], qdd[k]) for k in range(len(t))])
    p = fit_prior("description", "piper", [])
    p.joint["coulomb"][:] = 0.0
    p.joint["viscous"][:] = 0.0  # exactly the model that made tau
    err = np.abs(tau - prior_torque(p, t, q, qd, tau))[20:].mean()
    err_filic = np.abs(filic_residual(m, t, q, qd, tau))[20:].mean()
    assert err < 0.2 * err_filic, (err, err_filic)


def test_adaptive_estimate_filter_follows_contact_edges_without_more_noise():
    """The estimate's low-pass with the shipped constants, on a residual with 0.05 N*m noise and a contact
    from 1 s to 2 s (10 N*m on J1-J2 down to 0.5 on J6): in the 50 ms after each edge its error is under a
    tenth of the fixed 20 Hz low-pass's for the 5-10 N*m steps and under 0.4 of it for the small ones; while
    nothing happens its noise is within 10 % of it."""
    from calibration.next.prior_base import (
        ACCEL_CUTOFF_HZ,
        EST_BETA,
        EST_DERIV_HZ,
        EST_MIN_HZ,
        FILTER_ORDER,
        Lowpass,
    )

    t = np.arange(300) / RATE
    truth = np.where((t >= 1) & (t < 2), 1.0, 0.0)[:, None] * np.array([10, 10, 5, 1, 1, 0.5])
    r = truth + 0.05 * np.random.default_rng(0).normal(size=truth.shape)

    def err(f):
        return np.abs(np.array([f(x, 1 / RATE) for x in r]) - truth)

    fixed = err(Lowpass(ACCEL_CUTOFF_HZ, FILTER_ORDER))
    adaptive = err(Lowpass(EST_MIN_HZ, FILTER_ORDER, EST_BETA, EST_DERIV_HZ))
    edges = ((t >= 1) & (t < 1.05)) | ((t >= 2) & (t < 2.05))
    quiet = ((t > 0.3) & (t < 0.95)) | (t > 2.3)
    ratio = adaptive[edges].mean(0) / fixed[edges].mean(0)
    assert np.all(ratio[:3] < 0.1) and np.all(ratio < 0.4), ratio  # the cut-off rises with the step's size
    assert np.all(adaptive[quiet].mean(0) < 1.1 * fixed[quiet].mean(0))
    # beta 0 is the fixed low-pass
    np.testing.assert_allclose(err(Lowpass(ACCEL_CUTOFF_HZ, FILTER_ORDER, 0.0, EST_DERIV_HZ)), fixed)


def test_stream_equals_batch_and_restarts():
    t, q, qd, qdd = _motion(5.0)
    p = fit_prior("description", "piper", [])
    p.temp_ref = np.full(6, 30.0)
    p.joint["kt_temp"] = np.full(6, 0.001)
    tau = _true_arm_torque(q, qd, qdd, np.full(6, 0.2), np.full(6, 0.1), 0.1)
    temp = np.full_like(q, 35.0)
    s = PriorStream(p, RATE)
    ref = prior_torque(p, t, q, qd, tau, temp)
    out = [s.update(q[k], qd[k], tau[k], temp[k]) for k in range(len(t))]
    np.testing.assert_allclose(out, ref, atol=1e-9)
    assert not s.missing_temperature
    s.reset()  # a restart is a new run: the filters start again
    np.testing.assert_allclose([s.update(q[k], qd[k], tau[k], temp[k]) for k in range(100, 150)],
                               prior_torque(p, t[100:150], q[100:150], qd[100:150], tau[100:150],
                                            temp[100:150]), atol=1e-9)
    s.update(q[0], qd[0], tau[0])  # a temperature term and no temperature: flagged, reference used
    assert s.missing_temperature


def test_prior_round_trips_and_rejects_unknown_kinds_and_old_versions():
    p = fit_prior("description", "piper", [])
    p.ripple_period[1] = 0.17
    p.temp_ref[2] = 31.0
    back = Prior.from_dict(p.to_dict(), 6)
    np.testing.assert_array_equal(back.coefficients(), p.coefficients())
    np.testing.assert_array_equal(back.ripple_period, p.ripple_period)
    np.testing.assert_array_equal(back.temp_ref, p.temp_ref)  # NaN (no temperature) survives JSON as null
    assert (back.est_min_hz, back.est_beta, back.est_deriv_hz) == (p.est_min_hz, p.est_beta, p.est_deriv_hz)
    # saved before the adaptive estimate: evaluated as then, the fixed low-pass at the fit's cut-off
    old = Prior.from_dict({k: v for k, v in p.to_dict().items() if not k.startswith("est_")}, 6)
    assert (old.est_min_hz, old.est_beta) == (p.cutoff_hz, 0.0)
    with pytest.raises(ValueError):
        Prior.from_dict({**p.to_dict(), "est_beta": -1.0}, 6)
    with pytest.raises(ValueError):
        Prior.from_dict({**p.to_dict(), "kind": "magic"})
    with pytest.raises(ValueError, match="older version"):
        Prior.from_dict({k: v for k, v in p.to_dict().items() if k != "version"})
    with pytest.raises(ValueError):
        fit_prior("magic", "piper", [])


def _ck_with_prior(tmp_path):
    torch.manual_seed(0)
    m = NextModel(ModelConfig(n_in=18, n_out=6, history=10, hidden=16, head_hidden=16)).eval()
    rng = np.random.default_rng(0)
    ck = NextCheckpoint(model=m, normalizer=Normalizer(np.zeros(18), np.ones(18), np.zeros(6), np.ones(6)),
                        arm="piper", joint_names=[f"joint{i}" for i in range(1, 7)], units="N*m",
                        inputs="q,qd,dq", rate_hz=RATE, x_min=np.full(18, -5.0), x_max=np.full(18, 5.0),
                        prior=fit_prior("description", "piper", []))
    ck.prior.joint["coulomb"] = ck.prior.joint["coulomb"] + rng.uniform(0, 0.1, 6)  # not the description's
    return load_checkpoint(save_checkpoint(ck, tmp_path / "next"), arm="piper")


def test_a_damaged_prior_in_a_checkpoint_is_one_clear_error(tmp_path):
    import json

    from hardware.errors import ConfigError

    _ck_with_prior(tmp_path)
    meta = json.loads((tmp_path / "next.json").read_text())
    for bad in ({"coulomb": [0.1, 0.2]}, {"viscous": [float("nan")] * 6}, {"kind": "oracle"}, {"order": 9},
                {"temp_ref": [None] * 5}):
        (tmp_path / "next.json").write_text(json.dumps({**meta, "prior": {**meta["prior"], **bad}}))
        with pytest.raises(ConfigError, match="not a readable NEXT checkpoint"):
            load_checkpoint(tmp_path / "next")


def test_estimator_adds_the_prior_as_batch_does(tmp_path):
    ck = _ck_with_prior(tmp_path)
    assert ck.prior is not None and ck.prior.kind == "description"
    t, q, qd, qdd = _motion(3.0)
    tau = _true_arm_torque(q, qd, qdd, np.full(6, 0.2), np.full(6, 0.1), 0.1) + 0.7
    ref = batch_tau_f(ck, q, qd, q, tau)
    est = NextEstimator(ck)
    out = np.array([est.update(q[k], qd[k], q[k], tau[k]).tau_f for k in range(len(t))])
    np.testing.assert_allclose(out[9:], ref[9:], atol=1e-5)
    net_only = batch_tau_f(NextCheckpoint(**{**ck.__dict__, "prior": None}), q, qd, q)
    np.testing.assert_allclose(ref[9:] - net_only[9:], prior_torque(ck.prior, t, q, qd, tau)[9:], atol=1e-9)
    with pytest.raises(ValueError, match="needs tau"):
        batch_tau_f(ck, q, qd, q)
    bad = est.update(q[0], qd[0], q[0], np.full(6, np.nan))  # a bad torque: no prior, filters restart
    assert bad.flags & FLAG_NONFINITE and np.all(np.isnan(bad.tau_f))
    assert est.update(q[1], qd[1], q[1], tau[1]).flags & FLAG_NONFINITE == 0


def test_estimator_flags_a_missing_temperature(tmp_path):
    ck = _ck_with_prior(tmp_path)
    ck.prior.temp_ref = np.full(6, 30.0)
    ck.prior.joint["kt_temp"] = np.full(6, 0.001)
    est = NextEstimator(ck)
    t, q, qd, qdd = _motion(0.5)
    tau = _true_arm_torque(q, qd, qdd, np.full(6, 0.2), np.full(6, 0.1), 0.1)
    assert est.update(q[0], qd[0], q[0], tau[0], np.full(6, 35.0)).flags & FLAG_NO_TEMPERATURE == 0
    assert est.update(q[1], qd[1], q[1], tau[1]).flags & FLAG_NO_TEMPERATURE
    assert est.update(q[2], qd[2], q[2], tau[2], [35.0] * 6).flags & FLAG_NO_TEMPERATURE == 0


def test_calibrate_trains_on_top_of_the_identified_prior(tmp_path):
    from calibration.next.train import TrainConfig
    from calibration.report import calibrate_from_logs
    from hardware.recording.plain_log import save_plain_log

    t, q, qd, qdd = _motion(60.0)
    coulomb, viscous = np.full(6, 0.3), np.full(6, 0.1)
    tau = _true_arm_torque(q, qd, qdd, coulomb, viscous, 0.2)
    names = np.array([f"joint{i}" for i in range(1, 7)])
    train = save_plain_log(tmp_path / "a.npz", t=t, q=q, qd=qd, q_cmd=q, tau_m=tau, joint_names=names)
    t2, q2, qd2, qdd2 = _motion(20.0, seed=3)
    held = save_plain_log(tmp_path / "b.npz", t=t2, q=q2, qd=qd2, q_cmd=q2, joint_names=names,
                          tau_m=_true_arm_torque(q2, qd2, qdd2, coulomb, viscous, 0.2))
    cfg = TrainConfig(history=10, hidden=16, head_hidden=32, samples_per_epoch=1024, max_epochs=2, threads=1,
                      device="cpu", prior="auto")
    rep = calibrate_from_logs([train], tmp_path / "out", [held], arm="piper", cfg=cfg, plots=False)
    assert rep["prior"] == "identified"
    m = rep["methods"]
    assert m["prior"]["free_l1_mean"] < 0.5 * m["filic"]["free_l1_mean"]  # the payload is identified
    assert m["next"]["free_l1_mean"] < 0.5 * m["filic"]["free_l1_mean"]
    assert load_checkpoint(tmp_path / "out" / "next").prior.kind == "identified"
    plain = calibrate_from_logs([train], tmp_path / "plain", [held], arm="piper",
                                cfg=replace(cfg, prior="none"), plots=False)
    assert plain["prior"] == "none" and plain["methods"]["prior"]["free_l1_mean"] is None
