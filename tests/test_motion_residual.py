"""The motion-discounted contact score (policies/labels/motion_residual.py) and `--contact-score motion`: the
fit on synthetic estimates whose free-motion error follows the velocity, and the labelling that uses it."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from policies.labels import motion_residual as M
from policies.labels import phases as P

RATE = 100.0  # Hz
J = 3


def _set(seed: int = 0, seconds: float = 60.0):
    """(t [s], tau_ext (N, J) [N*m], q_dot (N, J) [rad/s], contact (N,) bool): joints at rest for 2 s in
    every 10 s and swinging otherwise, with an estimate whose error is Coulomb 0.4 N*m on joint 0 and viscous
    0.3 N*m/(rad/s) on joint 1 from joint 2's velocity, plus noise; a 1.2 N*m push on joint 1 for the last
    1.5 s of every 10 s, the arm slow there."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, seconds, 1 / RATE)
    qd = np.stack([np.sin(2 * np.pi * f * t + p) for f, p in ((0.23, 0), (0.17, 1), (0.31, 2))], 1) * 1.5
    contact = (t % 10.0) >= 8.5
    qd[(t % 10.0) < 2.0] = 0.0
    qd[contact] *= 0.1
    tau = 0.02 * rng.standard_normal((len(t), J))
    tau[:, 0] += 0.4 * np.sign(qd[:, 0])
    tau[:, 1] += 0.3 * qd[:, 2]
    tau[contact, 1] += 1.2
    return t, tau, qd, contact


def _rates(score, contact):
    lo, hi = P.recording_thresholds(score)
    lab = P.contact_runs(score, lo, hi)
    return lab[contact].mean(), lab[~contact].mean()


def test_the_fit_removes_the_motion_and_keeps_the_push():
    t, tau, qd, contact = _set()
    model = M.fit_motion_residual(tau, qd)
    assert abs(model.weights[1 + 0, 0] - 0.4) < 0.05  # the Coulomb term found: feature sign(q_dot_0), joint 0
    assert abs(model.weights[1 + J + 2, 1] - 0.3) < 0.05  # joint 2's velocity in joint 1's estimate
    recall, fp = _rates(M.residual_score(model, tau, qd), contact)
    recall_l1, fp_l1 = _rates(P.contact_score(tau), contact)
    assert recall > 0.95 and fp < 0.02
    assert fp_l1 > 0.2  # the swing reads as contact with ||tau_ext||_1: what the score is for


def test_a_new_set_is_scored_with_the_fit_of_another():
    _, tau, qd, _ = _set(seed=1)
    model = M.fit_motion_residual(tau, qd)
    _, tau2, qd2, contact2 = _set(seed=2, seconds=30.0)
    recall, fp = _rates(M.residual_score(model, tau2, qd2), contact2)
    assert recall > 0.95 and fp < 0.02


def test_non_finite_rows_are_left_out_and_score_nan():
    _, tau, qd, _ = _set(seconds=20.0)
    tau[5], qd[7, 1] = np.nan, np.inf
    model = M.fit_motion_residual(tau, qd)
    assert np.isfinite(model.weights).all() and (model.scale > 0).all()
    s = M.residual_score(model, tau, qd)
    assert np.isnan(s[5]) and not np.isfinite(s[7]) and np.isfinite(np.delete(s, [5, 7])).all()


def test_too_few_samples_or_mismatched_shapes_raise():
    with pytest.raises(ValueError, match="too few"):
        M.fit_motion_residual(np.zeros((10, J)), np.zeros((10, J)))
    with pytest.raises(ValueError, match="must both be"):
        M.fit_motion_residual(np.zeros((100, J)), np.zeros((100, J + 1)))


def test_round_trip_of_the_record():
    _, tau, qd, _ = _set(seconds=20.0)
    model = M.fit_motion_residual(tau, qd)
    back = M.MotionResidual.from_dict(model.to_dict())
    assert np.array_equal(back.weights, model.weights) and np.array_equal(back.scale, model.scale)


# --- through the labelling, on a recording ---------------------------------------------------------------

NAMES = [f"joint{i + 1}" for i in range(6)]
ROOT = "[[followers]]\nname = \"follower\"\narm = \"piper\"\n"


def _write(path, episodes: int = 3):
    """Episodes of _set() on joints 1-3 of a 6-joint follower (joints 4-6 at rest, noise only)."""
    from hardware.recording import Recorder
    from hardware.types import STATUS_ENABLED, JointState

    meta = {"simulated": "true", "rig_toml": ROOT}
    rec = Recorder(path, joint_names={"follower": NAMES}, t0=0.0, metadata=meta)
    off = 0.0
    for e in range(episodes):
        t, tau3, qd3, truth = _set(seed=10 + e, seconds=30.0)
        rng = np.random.default_rng(e)
        tau = np.concatenate([tau3, 0.02 * rng.standard_normal((len(t), 3))], 1)
        qd = np.concatenate([qd3, np.zeros((len(t), 3))], 1)
        q = np.cumsum(qd, 0) / RATE
        rec.start_episode(off, task="swing")
        for k in range(len(t)):
            s = JointState.empty(6, t=off + t[k])
            s.q[:], s.q_dot[:], s.status[:] = q[k], qd[k], STATUS_ENABLED
            rec.log_joint_state("follower", off + t[k], s)
            rec.log_follower_command("follower", off + t[k], q[k])
            rec.log_external_torque("follower", off + t[k], tau[k], bool(truth[k]))
        off += 30.5
        rec.stop_episode(off - 0.5, "success")
    rec.close()
    return path


def test_motion_score_labels_the_swing_free_and_the_push_contact(tmp_path):
    from policies.data.recordings import load_episodes
    from policies.labels import labelling as L

    eps, arms = load_episodes([_write(tmp_path / "swing.mcap")])
    rates = {}
    for score in ("l1", "motion"):
        th = L.resolve_thresholds(L.LabelChoice("recording", "off", score), None, eps, arms)
        tp = pos = fp = neg = 0
        for ep in eps:
            lab = L.label_episode(ep, arms, th)
            truth = ep.topic("/follower/tau_ext").fields["contact"].astype(bool)
            c = lab.phases == P.CONTACT
            tp, pos = tp + (c & truth).sum(), pos + truth.sum()
            fp, neg = fp + (c & ~truth).sum(), neg + (~truth).sum()
        rates[score] = (tp / pos, fp / neg, th)
    assert rates["motion"][0] > 0.95 and rates["motion"][1] < 0.03, rates
    assert rates["l1"][1] > 0.2, rates  # the default score takes the swing for contact
    d = rates["motion"][2].to_dict()  # what a training run records and resumes on
    assert d["score"] == "motion" and d["rule"].endswith(L.MOTION_RULE) and len(d["motion"]["scale"]) == 6
    assert "score" not in rates["l1"][2].to_dict()
    assert "motion residual" in str(rates["motion"][2].source)


def test_the_flag_round_trips_and_refuses_thresholds_in_nm(tmp_path, capsys):
    from factr2_teleop.cli import main
    from hardware.errors import UserError
    from policies.data.recordings import load_episodes
    from policies.labels import labelling as L
    from policies.labels.label_flags import add_label_arguments, thresholds_arg
    from policies.training.run_config import ThresholdsFlag

    p = argparse.ArgumentParser()
    add_label_arguments(p)
    got = thresholds_arg(p.parse_args(["--contact-score", "motion"]))
    assert got == L.LabelChoice("recording", "payload", "motion")
    assert thresholds_arg(p.parse_args(ThresholdsFlag("--thresholds").argv(got, None))) == got
    assert "--contact-score" not in ThresholdsFlag("--thresholds").argv(L.LabelChoice("recording"), None)
    path = _write(tmp_path / "swing.mcap", episodes=1)
    eps, arms = load_episodes([path])
    with pytest.raises(UserError, match="--thresholds recording"):
        L.resolve_thresholds(L.LabelChoice((1.0, 2.0), "off", "motion"), None, eps, arms)
    rc = main(["episodes", "phases", str(tmp_path), "--out", str(tmp_path / "ph"),
               "--contact-score", "motion"])
    out = capsys.readouterr().out
    assert rc == 0 and "motion residual" in out, out
    rc = main(["episodes", "phases", str(tmp_path), "--thresholds", "1:2", "--contact-score", "motion"])
    assert rc != 0


def test_smoothing_is_a_centred_mean_over_time_that_skips_nan():
    t = np.array([0.0, 0.01, 0.02, 0.03, 0.1, 0.2])
    f = np.array([1.0, 3.0, np.nan, 5.0, 7.0, np.nan])
    got = M.smooth_score(t, f, window_s=0.025)  # +-12.5 ms
    assert np.allclose(got[:5], [2.0, 2.0, 4.0, 5.0, 7.0]) and np.isnan(got[5])
    x = np.full(50, 2.5)
    assert np.array_equal(M.smooth_score(np.arange(50) / 500, x), x)  # a constant stays itself
