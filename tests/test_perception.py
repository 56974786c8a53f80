"""The simulated pose detector (hardware/sim/perception.py, SIMULATED): its statistics against its parameters
(bias across episodes, noise within one, rate, latency, occlusion, drops) and its parameter checks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hardware.errors import ConfigError
from hardware.sim.perception import (
    AGE_MAX_S,
    PerceptionParams,
    PoseDetector,
    perception_params,
    rotvec_exp,
    rotvec_log,
    seen_names,
    seen_vector,
)

QUIET = PerceptionParams(bias_pos_m=0.0, bias_rot_rad=0.0, noise_pos_m=0.0, noise_rot_rad=0.0, rate_hz=30.0,
                         latency_s=0.1, occlusion_radius_m=0.05, drop_prob=0.0, object_bias_pos_m=0.0,
                         object_bias_rot_rad=0.0)
FAR = np.array([5.0, 5.0, 5.0])  # m: a gripper far from every object
DT = 0.01  # s: the callers' decision period (100 Hz)


def _truth(p=(0.3, 0.1, 0.02), yaw=0.2):
    c, s = math.cos(yaw), math.sin(yaw)
    return {"a": (np.array(p, float), np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])),
            "b": (np.array([0.25, -0.1, 0.03]), np.eye(3))}


def _run(det, seconds, truth_at=None, grip_at=None, t0=0.0):
    out = []
    for k in range(round(seconds / DT)):
        t = t0 + k * DT
        truth = truth_at(t) if truth_at else _truth()
        out.append((t, truth, det.update(t, truth, grip_at(t) if grip_at else FAR)))
    return out


def test_bias_std_across_episodes_matches_its_parameters():
    p = PerceptionParams(bias_pos_m=0.003, bias_rot_rad=math.radians(1.0), noise_pos_m=0.0, noise_rot_rad=0.0,
                         drop_prob=0.0, object_bias_pos_m=0.002, object_bias_rot_rad=math.radians(0.5))
    det = PoseDetector(p, ("a", "b"))
    errs_a, errs_b, rot_a = [], [], []
    for seed in range(600):
        det.reset(np.random.default_rng(seed))
        t, truth, seen = _run(det, 0.2)[-1]
        errs_a.append(seen["a"].pos_m - truth["a"][0])
        errs_b.append(seen["b"].pos_m - truth["b"][0])
        rot_a.append(rotvec_log(seen["a"].rot @ truth["a"][1].T))
    ea, eb, ra = np.array(errs_a), np.array(errs_b), np.array(rot_a)
    total = math.hypot(0.003, 0.002)
    assert np.allclose(ea.std(0), total, rtol=0.12) and np.allclose(eb.std(0), total, rtol=0.12)
    assert np.allclose(ea.mean(0), 0.0, atol=4 * total / math.sqrt(600))
    # the camera's share is common to both objects: their biases correlate by 0.003^2 / total^2
    corr = np.mean([np.corrcoef(ea[:, i], eb[:, i])[0, 1] for i in range(3)])
    assert abs(corr - 0.003 ** 2 / total ** 2) < 0.1
    assert np.allclose(ra.std(0), math.radians(math.hypot(1.0, 0.5)), rtol=0.12)
    # one episode: the bias stays (a static scene seen twice gives the same answer)
    det.reset(np.random.default_rng(7))
    a1 = _run(det, 0.2)[-1][2]["a"].pos_m
    a2 = _run(det, 0.5, t0=0.2)[-1][2]["a"].pos_m
    assert np.allclose(a1, a2)


def test_noise_std_within_an_episode_matches_its_parameters():
    p = PerceptionParams(bias_pos_m=0.004, noise_pos_m=0.001, noise_rot_rad=math.radians(0.5), rate_hz=100.0,
                         latency_s=0.0, drop_prob=0.0, object_bias_pos_m=0.0, bias_rot_rad=0.0,
                         object_bias_rot_rad=0.0)
    det = PoseDetector(p, ("a", "b"))
    det.reset(np.random.default_rng(3))
    rows = _run(det, 20.0)
    pos = np.array([s["a"].pos_m for _, _, s in rows])
    rot = np.array([rotvec_log(s["a"].rot @ tr["a"][1].T) for _, tr, s in rows])
    assert len(rows) == 2000 and det.frames == 2000
    assert np.allclose(pos.std(0), 0.001, rtol=0.1)
    assert np.allclose(rot.std(0), math.radians(0.5), rtol=0.1)


def test_rate_holds_between_frames_and_latency_delays_them():
    det = PoseDetector(replace_q(rate_hz=20.0, latency_s=0.1), ("a", "b"))
    det.reset(np.random.default_rng(0))
    v = np.array([0.1, 0.0, 0.0])  # m/s: a moving object, its seen position tells when it was captured

    def moving(t):
        tr = _truth()
        return {"a": (tr["a"][0] + v * t, tr["a"][1]), "b": tr["b"]}

    rows = _run(det, 3.0, truth_at=moving)
    assert abs(det.frames / 3.0 - 20.0) <= 1.0
    for t, _, s in rows:
        if t < 0.1 - 1e-9:
            assert not np.isfinite(s["a"].age_s) and not s["a"].visible  # nothing has arrived yet
            continue
        t_cap = (s["a"].pos_m[0] - _truth()["a"][0][0]) / v[0]
        assert s["a"].age_s == pytest.approx(t - t_cap, abs=1e-9)
        assert 0.1 - 1e-9 <= s["a"].age_s < 0.1 + 1.0 / 20.0 + 1e-9
    held = [s["a"].pos_m[0] for _, _, s in rows[20:]]
    changes = np.count_nonzero(np.diff(held))
    assert abs(changes - 20.0 * 2.8) <= 2  # one new value per frame, held in between


def replace_q(**kw) -> PerceptionParams:
    from dataclasses import replace

    return replace(QUIET, **kw)


def test_occlusion_near_the_gripper_freezes_the_detection():
    det = PoseDetector(replace_q(latency_s=0.05), ("a", "b"))
    det.reset(np.random.default_rng(0))
    a0 = _truth()["a"][0]

    def carried(t):  # the object moves with the gripper from t = 1 s to 2 s
        tr = _truth()
        return {"a": (a0 + [0.0, 0.0, 0.1 * max(0.0, min(t, 2.0) - 1.0)], tr["a"][1]), "b": tr["b"]}

    def grip(t):
        return carried(t)["a"][0] + [0, 0, 0.02] if 1.0 <= t < 2.0 else FAR

    rows = _run(det, 3.0, truth_at=carried, grip_at=grip)
    during = [s for t, _, s in rows if 1.2 <= t < 2.0]
    assert all(not s["a"].visible for s in during) and all(s["b"].visible for s in during)
    assert all(np.allclose(s["a"].pos_m, a0) for s in during)  # frozen at the last view before the hand
    assert during[-1]["a"].age_s > 0.8
    after = rows[-1][2]["a"]
    assert after.visible and after.pos_m[2] == pytest.approx(a0[2] + 0.1)


def test_drop_rate_matches_its_parameter():
    det = PoseDetector(replace_q(drop_prob=0.2, latency_s=0.0, rate_hz=100.0), ("a", "b"))
    det.reset(np.random.default_rng(1))
    rows = _run(det, 30.0)
    vis = np.array([[s["a"].visible, s["b"].visible] for _, _, s in rows])
    assert abs((1 - vis.mean()) - 0.2) < 0.02


def test_reset_repeats_for_a_seed_and_differs_across_seeds():
    det = PoseDetector(PerceptionParams(), ("a", "b"))
    seq = []
    for seed in (5, 5, 6):
        det.reset(np.random.default_rng(seed))
        seq.append(np.array([s["a"].pos_m for _, _, s in _run(det, 1.0)[20:]]))
    assert np.array_equal(seq[0], seq[1]) and not np.allclose(seq[0], seq[2])


def test_seen_vector_is_finite_and_named():
    det = PoseDetector(PerceptionParams(), ("a", "b"))
    det.reset(np.random.default_rng(0))
    s0 = det.update(0.0, _truth(), FAR)  # nothing delivered yet (latency)
    v0 = seen_vector(s0, ("a", "b"))
    assert v0.dtype == np.float32 and v0.shape == (22,) and np.all(np.isfinite(v0))
    assert len(seen_names(("a", "b"))) == 22
    assert v0[9] == 0.0 and v0[10] == AGE_MAX_S
    s1 = _run(det, 0.5)[-1][2]
    v1 = seen_vector(s1, ("a", "b"))
    assert v1[9] == 1.0 and 0.0 <= v1[10] < 0.2
    assert np.allclose(v1[3:6], s1["a"].rot[:, 0], atol=1e-6)


def test_rotvec_exp_log_round_trip():
    w = np.array([0.1, -0.2, 0.3])
    assert np.allclose(rotvec_log(rotvec_exp(w)), w)
    assert np.allclose(rotvec_exp(w) @ rotvec_exp(w).T, np.eye(3))


@pytest.mark.parametrize("table", [{"bias_pos_mm": 3}, {"bias_pos_m": "x"}, {"bias_pos_m": -0.001},
                                   {"rate_hz": 0}, {"drop_prob": 1.5}, {"latency_s": float("nan")},
                                   {"noise_rot_rad": True}, ["bias_pos_m", 1]])
def test_garbage_params_are_refused_with_one_line(table):
    with pytest.raises(ConfigError) as e:
        perception_params(table, where="rig.toml: twin.perception")
    msg = str(e.value)
    assert "\n" not in msg and "twin.perception" in msg and "fix:" in msg


def test_params_override_the_defaults():
    p = perception_params({"bias_pos_m": 0.005, "rate_hz": 15})
    assert p.bias_pos_m == 0.005 and p.rate_hz == 15.0 and p.latency_s == PerceptionParams().latency_s
    assert perception_params(None) == PerceptionParams()
    with pytest.raises(TypeError):
        PoseDetector({"bias_pos_m": 0.0}, ("a",))
