"""Tare on grasp (policies/labels/tare.py): held-object detection, the load fit, its checks, and the labelling
that uses it (thresholds on the tared scores, --no-tare, the run's record)."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from policies.labels import phases as P
from policies.labels import tare as T

RATE = 100.0  # Hz
SECONDS = 20.0
GRASP_S, LIFT_S, RELEASE_S = 2.0, 3.5, 16.0  # close command, start of the transport, open command [s]
CONTACT_S = (10.0, 11.0)  # a real contact in the middle of the carry [s]
# 0.5 kg held between the fingers: its centre 15 cm beyond the last joint along z (the Piper's gripper centre
# point is at 13.5 cm), as (m [kg], m*c [kg*m]) in the last joint's frame
THETA = np.array([0.5, 0.0, 0.0, 0.5 * 0.15])
ROOT = "[[followers]]\nname = \"follower\"\narm = \"piper\"\n"


NAMES = [f"joint{i + 1}" for i in range(6)]


def _flange():
    """The Piper's payload regressor for (m, m*c) in its last joint's frame: makes the synthetic loads."""
    from policies.labels.tare_recording import payload_regressor

    return payload_regressor("piper", NAMES)


def _regressor():
    """The tare's payload model of the Piper (about its gripper's centre point)."""
    from policies.labels.tare_recording import payload_model

    return payload_model("piper", NAMES)[0]


def _gripper(t: np.ndarray, object_m: float | None = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(stroke, command) [m]: open 0.04 (commanded 0.07), closed at GRASP_S (fingers travel 0.1 m/s and
    stop on an object of width object_m, or reach 0 with None), opened at RELEASE_S."""
    command = np.where((t >= GRASP_S) & (t < RELEASE_S), 0.0, 0.07)
    stop = 0.0 if object_m is None else object_m
    closing = np.clip(0.04 - 0.1 * np.clip(t - GRASP_S - 0.05, 0, None), stop, 0.04)
    opening = np.clip(stop + 0.1 * np.clip(t - RELEASE_S - 0.05, 0, None), stop, 0.04)
    stroke = np.where(t < GRASP_S, 0.04, np.where(t < RELEASE_S, closing, opening))
    return stroke, command


def _episode(seed: int = 0, contact: bool = True, object_m: float | None = 0.01):
    """t [s], q (N, 6) [rad]: still, then a transport that turns the shoulder, elbow and wrist (the load's
    torques change with it); tau_ext: 0.05 N*m noise, the held 0.5 kg while holding, a 1.5 N*m push on
    joints 2-3 during CONTACT_S; stroke, command [m]; the true contact (N,) bool."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(SECONDS * RATE)) / RATE
    u = np.clip((t - LIFT_S) / (RELEASE_S - 1.0 - LIFT_S), 0, 1)
    s = 0.5 - 0.5 * np.cos(np.pi * u)  # smooth 0 -> 1
    q0 = np.array([0.0, 1.2, -1.0, 0.0, 0.6, 0.0])
    q = q0 + np.outer(s, [1.2, -0.5, 0.6, 0.8, -0.6, 1.0])
    stroke, command = _gripper(t, object_m)
    held = T.held_mask(t, stroke, command)
    tau = rng.normal(0, 0.05, (len(t), 6)) + held[:, None] * np.einsum("knp,p->kn", _flange()(q), THETA)
    truth = contact & (t >= CONTACT_S[0]) & (t < CONTACT_S[1])
    tau[truth, 1:3] += 1.5
    return t, q, tau, stroke, command, truth


def test_held_from_the_fingers_settling_on_an_object_to_the_release():
    t = np.arange(int(SECONDS * RATE)) / RATE
    held = T.held_mask(t, *_gripper(t))
    (i0, i1), = T.stretches(held)
    # the fingers stop at 0.01 m after 0.35 s of travel, then stand still SETTLE_S; the open command ends it
    assert t[i0] == pytest.approx(GRASP_S + 0.05 + 0.3 + T.SETTLE_S, abs=0.06)
    assert t[i1] == pytest.approx(RELEASE_S)
    assert not T.held_mask(t, *_gripper(t, object_m=None)).any()  # closed on nothing: stroke meets command
    stroke, command = _gripper(t)
    assert not T.held_mask(t, stroke, np.full_like(t, np.nan)).any()  # no command recorded: no hold seen
    with pytest.raises(ValueError):
        T.held_mask(t, stroke, command[:-1])


def test_a_close_command_the_fingers_have_not_started_on_is_not_a_hold():
    t = np.arange(200) / RATE
    command = np.where(t >= 0.5, 0.0, 0.07)
    stroke = np.where(t < 0.5 + 0.15, 0.04, np.clip(0.04 - 0.1 * (t - 0.65), 0.0, 0.04))  # 0.15 s lag, empty
    assert not T.held_mask(t, stroke, command).any()


def test_payload_tare_keeps_a_carry_free_and_still_finds_the_contact():
    t, q, tau, stroke, command, truth = _episode()
    held = T.held_mask(t, stroke, command)
    lo, hi = 0.8, 1.2  # N*m: above the noise (6 x 0.05 x 0.8 ~ 0.24), below the push (3)
    raw = P.hysteresis(P.contact_score(tau), lo, hi)
    assert raw[held & ~truth].mean() > 0.9  # untared, the 0.5 kg reads as contact for the whole carry
    res = T.held_load(t, tau, q, held, _regressor())
    assert res.skipped == [""] and res.thetas[0][0] == pytest.approx(THETA[0], rel=0.05)
    c = P.hysteresis(P.contact_score(T.tared(tau, res.load)), lo, hi)
    assert c[truth].mean() > 0.98 and c[~truth].mean() < 0.005
    ph = P.label_phases(t, c)
    assert (ph[held & ~truth & (t < CONTACT_S[0] - P.PRE_CONTACT_S)] == P.FREE).all()


def test_a_constant_bias_misses_a_load_whose_torque_follows_the_configuration():
    t, q, tau, stroke, command, truth = _episode(contact=False)
    held = T.held_mask(t, stroke, command)
    err = {}
    for name, reg in (("payload", _regressor()), ("bias", T.bias_regressor)):
        res = T.held_load(t, tau, q, held, reg)
        err[name] = np.percentile(P.contact_score(T.tared(tau, res.load))[held], 95)
    assert err["payload"] < 0.5 < 2 * err["payload"] < err["bias"], err


def test_no_grasp_leaves_the_score_unchanged():
    t, q, tau, stroke, command, _ = _episode(object_m=None)
    held = T.held_mask(t, stroke, command)
    res = T.held_load(t, tau, q, held, _regressor())
    assert not held.any() and res.stretches == [] and (T.tared(tau, res.load) == tau).all()


def test_a_fit_that_is_no_load_leaves_the_stretch_untared():
    from policies.labels.tare_recording import payload_model

    t, q, tau, stroke, command, _ = _episode(contact=False)
    held = T.held_mask(t, stroke, command)
    (i0, _), = T.stretches(held)
    w0, w1 = T.tare_window(t, q, i0, len(t))
    lifted = tau.copy()
    lifted[w0:w1] -= 2 * np.einsum("knp,p->kn", _flange()(q[w0:w1]), THETA)  # a push up: "negative mass"
    res = T.held_load(t, lifted, q, held, *payload_model("piper", NAMES))
    assert "not positive" in res.skipped[0] and (res.load == 0).all()
    quiet = np.zeros_like(tau)  # nothing held in fact, noise only in the window: a "load" that adds noise
    quiet[w0:w1] = np.random.default_rng(1).normal(0, 0.05, (w1 - w0, 6))
    res = T.held_load(t, quiet, q, held, T.bias_regressor)
    assert res.skipped[0] == "does not make the carry quieter" and (res.load == 0).all()


def test_fit_load_is_least_squares_and_needs_samples():
    rng = np.random.default_rng(0)
    tau = rng.normal(0.3, 0.01, (50, 3))
    tau[0] = np.nan  # no estimate yet: left out
    assert T.fit_load(T.bias_regressor(np.zeros((50, 3))), tau) == pytest.approx(np.nanmean(tau, 0))
    assert T.fit_load(T.bias_regressor(np.zeros((5, 3))), tau[:5]) is None
    assert T.tare_window(np.arange(10.0), np.zeros((10, 2)), 0, 10) is None  # never moved: nothing lifted


# -- labelling of recordings ---------------------------------------------------------------------------


def _write(path, episodes: int = 2):
    """A recording of _episode()s with the follower's gripper, command and tau_ext, rig arm "piper"."""
    from hardware.recording import Recorder
    from hardware.types import STATUS_ENABLED, JointState

    meta = {"simulated": "true", "rig_toml": ROOT}
    rec = Recorder(path, joint_names={"follower": NAMES}, t0=0.0, metadata=meta)
    off = 0.0
    for e in range(episodes):
        t, q, tau, stroke, command, truth = _episode(seed=e)
        rec.start_episode(off, task="carry")
        for k in range(len(t)):
            s = JointState.empty(6, t=off + t[k])
            s.q[:], s.q_dot[:], s.status[:] = q[k], 0.0, STATUS_ENABLED
            s.gripper_pos = stroke[k]
            rec.log_joint_state("follower", off + t[k], s)
            rec.log_follower_command("follower", off + t[k], q[k], gripper=command[k])
            rec.log_external_torque("follower", off + t[k], tau[k], bool(truth[k]))
        off += SECONDS + 0.5
        rec.stop_episode(off - 0.5, "success")
    rec.close()
    return path


def test_labels_and_recording_thresholds_use_the_tared_scores(tmp_path):
    from policies.data.recordings import load_episodes
    from policies.labels import labelling as L

    eps, arms = load_episodes([_write(tmp_path / "carry.mcap")])
    assert arms.arm_models == ("piper",)
    on = L.resolve_thresholds("recording", None, eps, arms)  # the library's default: tared
    off = L.resolve_thresholds(L.LabelChoice("recording", "off"), None, eps, arms)
    assert on.tare == "payload" and on.source.get("tared")
    assert off.tare == "off" and not off.source.get("tared")
    assert "tared" in str(on.source) and "tared" not in str(off.source)
    assert on.to_dict()["tare"] == "payload"  # what a training run records as meta["phases"]
    assert "tare" not in off.to_dict()  # as before the tare: such runs still resume
    lab_on, lab_off = (L.label_episode(eps[0], arms, th) for th in (on, off))
    carry = lab_on.held & ((lab_on.t - lab_on.t[0]) < CONTACT_S[0] - P.PRE_CONTACT_S)
    assert carry.sum() > 400 and (lab_on.phases[carry] == P.FREE).mean() > 0.99
    assert (lab_off.phases[carry] == P.CONTACT).mean() > 0.9  # untared, the carry reads as contact
    push = (lab_on.t - lab_on.t[0] >= CONTACT_S[0]) & (lab_on.t - lab_on.t[0] < CONTACT_S[1])
    assert (lab_on.phases[push] == P.CONTACT).mean() > 0.95
    assert (lab_on.tau_ext == lab_off.tau_ext).all()  # the policy's force input is not tared
    assert "1/1 holds tared" in lab_on.source


def test_no_tare_flag_reaches_the_thresholds_and_the_phases_command(tmp_path, capsys):
    from factr2_teleop.cli import main
    from policies.labels.label_flags import add_label_arguments, thresholds_arg
    from policies.labels.labelling import LabelChoice

    p = argparse.ArgumentParser()
    add_label_arguments(p)
    assert thresholds_arg(p.parse_args([])) == LabelChoice("recording", "payload")
    got = thresholds_arg(p.parse_args(["--no-tare", "--thresholds", "1:2"]))
    assert got == LabelChoice((1.0, 2.0), "off")
    _write(tmp_path / "carry.mcap", episodes=1)
    for extra, word in (([], "tare payload"), (["--no-tare"], "tare off")):
        rc = main(["episodes", "phases", str(tmp_path), "--out", str(tmp_path / "ph"), *extra])
        out = capsys.readouterr().out
        assert rc == 0 and word in out.splitlines()[0], out
    assert len(list((tmp_path / "ph").glob("*.png"))) == 1


def test_about_point_is_the_same_load_recentred():
    rng = np.random.default_rng(0)
    Y, c = rng.normal(size=(7, 6, 4)), np.array([0.0, 0.01, 0.135])
    theta = np.array([0.4, 0.01, -0.02, 0.06])  # (m, m*c_obj) about the last joint
    recentred = np.r_[theta[0], theta[1:] - theta[0] * c]  # (m, m*(c_obj - c))
    assert np.einsum("knp,p->kn", T.about_point(Y, c), recentred) == pytest.approx(Y @ theta)
    assert T.from_point(recentred, c) == pytest.approx(theta)
