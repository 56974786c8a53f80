"""NEXT's physics prior: the identified fit recovers a mis-described arm, streaming equals batch, the
checkpoint carries it, and calibrate trains on top of it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
import torch

from calibration.next.checkpoint import NextCheckpoint, load_checkpoint, save_checkpoint
from calibration.next.data import Normalizer
from calibration.next.estimator import NextEstimator, batch_tau_f
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


def _true_arm_torque(q, qd, qdd, coulomb, viscous, extra_mass_kg):
    """The 'real' arm: the description with a payload on the last link that nobody declared, and friction."""
    from hardware.sim.example_effects import with_payload

    m = with_payload(pinocchio_model("piper"), extra_mass_kg, [0.0, 0.0, 0.05], 1e-4)
    d = m.createData()
    rb = np.stack([pin.rnea(m, d, q[k], qd[k], qdd[k]) for k in range(len(q))])
    return rb + coulomb * np.tanh(qd / 0.02) + viscous * qd


def test_identified_prior_recovers_an_undeclared_payload_and_friction():
    t, q, qd, qdd = _motion(90.0)
    coulomb = np.array([0.4, 0.5, 0.3, 0.1, 0.12, 0.08])
    viscous = np.array([0.2, 0.1, 0.15, 0.05, 0.03, 0.02])
    tau = _true_arm_torque(q, qd, qdd, coulomb, viscous, extra_mass_kg=0.3)
    p = fit_prior("identified", "piper", [(t, q, qd, tau)])
    t2, q2, qd2, qdd2 = _motion(30.0, seed=5)  # other motion: generalisation, not memory
    tau2 = _true_arm_torque(q2, qd2, qdd2, coulomb, viscous, extra_mass_kg=0.3)
    err_id = np.abs(tau2 - prior_torque(p, t2, q2, qd2))[20:].mean(0)
    err_desc = np.abs(tau2 - prior_torque(description_prior("piper"), t2, q2, qd2))[20:].mean(0)
    assert err_id.mean() < 0.25 * err_desc.mean(), (err_id, err_desc)
    np.testing.assert_allclose(p.coulomb, coulomb, atol=0.05)


def test_stream_equals_batch_and_restarts():
    t, q, qd, _ = _motion(5.0)
    p = fit_prior("description", "piper", [])
    s = PriorStream(p, RATE)
    ref = prior_torque(p, t, q, qd)
    np.testing.assert_allclose([s.update(q[k], qd[k]) for k in range(len(t))], ref, atol=1e-9)
    s.reset()  # a restart is a new run: the acceleration filter starts again
    np.testing.assert_allclose([s.update(q[k], qd[k]) for k in range(100, 150)],
                               prior_torque(p, t[100:150], q[100:150], qd[100:150]), atol=1e-9)


def test_prior_round_trips_and_rejects_unknown_kinds():
    p = fit_prior("description", "piper", [])
    back = Prior.from_dict(p.to_dict())
    for k in ("d_theta", "d_armature", "coulomb", "viscous"):
        np.testing.assert_array_equal(getattr(back, k), getattr(p, k))
    with pytest.raises(ValueError):
        Prior.from_dict({**p.to_dict(), "kind": "magic"})
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
    ck.prior.coulomb = ck.prior.coulomb + rng.uniform(0, 0.1, 6)  # not the description's own numbers
    return load_checkpoint(save_checkpoint(ck, tmp_path / "next"), arm="piper")


def test_a_damaged_prior_in_a_checkpoint_is_one_clear_error(tmp_path):
    import json

    from hardware.errors import ConfigError

    _ck_with_prior(tmp_path)
    meta = json.loads((tmp_path / "next.json").read_text())
    for bad in ({"coulomb": [0.1, 0.2]}, {"viscous": [float("nan")] * 6}, {"kind": "oracle"}):
        (tmp_path / "next.json").write_text(json.dumps({**meta, "prior": {**meta["prior"], **bad}}))
        with pytest.raises(ConfigError, match="not a readable NEXT checkpoint"):
            load_checkpoint(tmp_path / "next")


def test_estimator_adds_the_prior_as_batch_does(tmp_path):
    ck = _ck_with_prior(tmp_path)
    assert ck.prior is not None and ck.prior.kind == "description"
    t, q, qd, _ = _motion(3.0)
    tau = prior_torque(ck.prior, t, q, qd) + 0.7  # free motion seen by the prior + a constant offset
    ref = batch_tau_f(ck, q, qd, q)
    est = NextEstimator(ck)
    out = np.array([est.update(q[k], qd[k], q[k], tau[k]).tau_f for k in range(len(t))])
    np.testing.assert_allclose(out[9:], ref[9:], atol=1e-5)
    net_only = batch_tau_f(NextCheckpoint(**{**ck.__dict__, "prior": None}), q, qd, q)
    np.testing.assert_allclose(ref[9:] - net_only[9:], prior_torque(ck.prior, t, q, qd)[9:], atol=1e-9)


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
