"""The data-only prior (calibration/next/data_prior.py): a grey box without an arm description under NEXT
(issue 23, item 2), and what the report says the network adds over its prior (item 3)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from calibration.next.checkpoint import load_checkpoint
from calibration.next.data_prior import DataPriorStream, columns, data_prior_torque, fit_data_prior, n_columns
from calibration.next.estimator import NextEstimator, batch_tau_f
from calibration.next.train import TrainConfig
from calibration.report import calibrate_from_logs, network_adds

torch.set_num_threads(1)


def _arm(seconds: float, seed: int = 0, rate_hz: float = 100.0):
    """A 3-joint arm nobody described: gravity of two links, Coulomb + viscous friction, a current offset.
    -> t [s], q [rad], qd [rad/s], current [A]."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    f, ph = rng.uniform(0.1, 0.4, 3), rng.uniform(0, 6, 3)
    q = 1.2 * np.sin(2 * np.pi * f * t[:, None] + ph)
    qd = 1.2 * 2 * np.pi * f * np.cos(2 * np.pi * f * t[:, None] + ph)
    s1, s12 = np.sin(q[:, 1]), np.sin(q[:, 1] + q[:, 2])
    g = np.stack([np.zeros_like(s1), 3.0 * s1 + 1.0 * s12, 1.0 * s12], 1)
    return t, q, qd, g + 0.4 * np.tanh(qd / 0.02) + 0.2 * qd + np.array([0.1, -0.2, 0.05])


def test_columns_shape_and_stream_equals_batch():
    t, q, qd, cur = _arm(20.0)
    assert columns(q[:5], qd[:5], qd[:5]).shape == (5, 3, n_columns(3))
    p = fit_data_prior([(t, q, qd, cur)])
    batch = data_prior_torque(p, t, q, qd, cur)
    s = DataPriorStream(p, 100.0)
    one = np.array([s.update(q[k], qd[k], cur[k]) for k in range(len(t))])
    np.testing.assert_allclose(one, batch, atol=1e-9)
    s.reset()
    np.testing.assert_allclose(s.update(q[0], qd[0], cur[0]), batch[0], atol=1e-12)


def test_data_prior_explains_gravity_friction_and_offset_on_unseen_motion():
    """Three runs: the basis is chosen by leave-one-run-out; joints 2-3 need the angle sums (full basis)."""
    p = fit_data_prior([_arm(40.0, seed) for seed in (0, 1, 2)])
    t2, q2, qd2, cur2 = _arm(30.0, seed=4)
    resid = np.abs(cur2 - data_prior_torque(p, t2, q2, qd2, cur2))[20:]
    assert resid.mean() < 0.05 * np.abs(cur2).mean()  # the grey box knows the structure: < 5 % left
    assert p.basis[1:] == ["full", "full"]
    one = fit_data_prior([_arm(40.0, 0)])  # one short run: the cross-validation cannot tell, small basis
    assert one.basis == ["small"] * 3


def test_auto_prior_without_description_is_data_only_and_the_network_learns_the_rest(tmp_path):
    """No arm description and current in A: `--prior auto` = data-only; the checkpoint carries it; the
    streaming estimator adds it as the batch does; the report says what the network adds per joint."""
    names = np.array(["a", "b", "c"])
    for name, secs, seed in (("train0", 30.0, 0), ("train1", 30.0, 1), ("train2", 30.0, 2),
                             ("held", 20.0, 7)):
        t, q, qd, cur = _arm(secs, seed)
        np.savez(tmp_path / f"{name}.npz", t=t, q=q, qd=qd, q_cmd=q, current=cur, joint_names=names)
    cfg = TrainConfig(history=10, hidden=8, head_hidden=16, samples_per_epoch=512, max_epochs=2, threads=1,
                      device="cpu", prior="auto")
    rep = calibrate_from_logs([tmp_path / f"train{i}.npz" for i in range(3)], tmp_path / "out",
                              [tmp_path / "held.npz"], cfg=cfg, plots=False)
    assert rep["prior"] == "data-only" and rep["units"] == "A"
    m = rep["methods"]
    assert m["prior"]["free_l1_mean"] < 0.1 * m["raw"]["free_l1_mean"]
    adds = rep["network_adds"]
    assert adds["baseline"] == "prior" and adds["contact"] is None
    assert adds["free"]["prior_l1"] == pytest.approx(m["prior"]["free_l1"])
    assert adds["free"]["gain"] == pytest.approx(np.subtract(m["prior"]["free_l1"], m["next"]["free_l1"]))
    assert rep["train_seconds_to_within_5pct"] <= rep["train_seconds"] and rep["train_stop"]
    md = (tmp_path / "out" / "report.md").read_text()
    assert "What the network adds over prior, held-out free [A]" in md
    ck = load_checkpoint(tmp_path / "out" / "next")
    assert ck.prior.kind == "data-only"
    assert json.loads((tmp_path / "out" / "next.json").read_text())["prior"]["kind"] == "data-only"
    t, q, qd, cur = _arm(3.0, 9)
    ref = batch_tau_f(ck, q, qd, q, cur)
    est = NextEstimator(ck)
    out = np.array([est.update(q[k], qd[k], q[k], cur[k]).tau_f for k in range(len(t))])
    np.testing.assert_allclose(out[9:], ref[9:], atol=1e-5)


def test_network_adds_falls_back_to_raw_without_a_prior():
    m = {"prior": {"free_l1": None, "contact_l1": None}, "raw": {"free_l1": [2.0, 4.0], "contact_l1": None},
         "next": {"free_l1": [1.0, 1.0], "contact_l1": None}}
    a = network_adds(m)
    assert a["baseline"] == "raw" and a["free"]["gain"] == [1.0, 3.0] and a["free"]["ratio_mean"] == 1 / 3
