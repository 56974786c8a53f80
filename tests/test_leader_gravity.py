"""Leader gravity identification (calibration/leader_gravity.py): the math on arrays, the file teleop reads,
and one short run on the twin's GELLO (SIMULATED), whose true body is heavier than its description."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calibration import leader_gravity as lg
from factr2_teleop.teleop.leader_law import arm_model_fns
from hardware.arms import load_arm
from hardware.errors import ConfigError


@pytest.fixture(scope="module")
def gello():
    arm = load_arm("gello_piper")
    return arm, arm.pinocchio_model()


def _g(model, q):
    return pin.computeGeneralizedGravity(model, model.createData(), np.asarray(q, float))


def test_regressor_times_description_params_is_gravity(gello):
    arm, model = gello
    Q = lg.hold_poses(arm.limits.q_min, arm.limits.q_max, 5, seed=1)
    Y = lg.gravity_regressor(model, Q)
    p0 = lg.description_params(model)
    assert Y.shape == (5, 6, p0.size)
    np.testing.assert_allclose(Y @ p0.reshape(-1), np.array([_g(model, q) for q in Q]), atol=1e-12)


def test_fit_recovers_a_heavier_leader_from_noisy_holds(gello):
    arm, model = gello
    p0 = lg.description_params(model)
    rng = np.random.default_rng(0)
    p_true = p0 * rng.uniform(1.0, 1.3, size=(p0.shape[0], 1))  # heavier links
    p_true[:, 1:] += p_true[:, :1] * rng.uniform(-0.005, 0.005, size=(p0.shape[0], 3))  # COM off by <= 5 mm
    true_model = lg.model_with_params(model, p_true)
    g_fn = lambda q: _g(model, q)  # noqa: E731
    Q = lg.hold_poses(arm.limits.q_min, arm.limits.q_max, 20, seed=2, q_home=arm.q_home, g_fn=g_fn,
                      tau_max=arm.limits.tau_max)
    tau = np.array([_g(true_model, q) for q in Q]) + rng.normal(0, 0.003, size=(20, 6))
    fit = lg.fit_gravity_params(lg.gravity_regressor(model, Q[:12]), tau[:12], p0)
    fitted = lg.model_with_params(model, fit)
    before = lg.rest_residual(tau[12:], [_g(model, q) for q in Q[12:]])
    after = lg.rest_residual(tau[12:], [_g(fitted, q) for q in Q[12:]])
    assert before["rms_mean_nm"] > 0.01  # the description is visibly wrong
    assert after["rms_mean_nm"] < 0.3 * before["rms_mean_nm"]
    assert after["max_nm_all"] < 0.015  # down to the noise


def test_poses_stay_holdable_on_the_way_and_holds_are_screened(gello):
    arm, model = gello
    lim = arm.limits
    Q = lg.hold_poses(lim.q_min, lim.q_max, 8, seed=0, q_home=arm.q_home, g_fn=lambda q: _g(model, q),
                      tau_max=lim.tau_max)
    assert len(Q) == 8 and np.allclose(Q[0], arm.q_home)
    for q in Q[1:]:
        for s in np.linspace(0, 1, 11):
            assert np.all(np.abs(_g(model, Q[0] + s * (q - Q[0]))) <= lg.LOAD_FRAC * lim.tau_max + 1e-12)
    tau = np.array([_g(model, q) for q in Q])
    rest = Q.copy()
    rest[1, 2] += 0.5  # fell away from its pose
    tau[2, 1] = lim.tau_max[1]  # saturated
    assert lg.good_holds(rest, tau, Q, lim.tau_max).tolist() == [True, False, False] + [True] * 5
    kp, kd = lg.HoldGains().gains(np.array([0.02, 1e-4]))
    assert kp[0] == pytest.approx(18.0) and kp[1] == lg.HoldGains().kp_min and np.all(kd > 0)
    np.testing.assert_allclose(lg.hold_torque(np.ones(2), np.zeros(2), np.ones(2), np.ones(2), kp, kd),
                               1 + kp - kd)


def test_file_round_trip_feeds_the_leader_law(gello, tmp_path):
    arm, model = gello
    p = lg.description_params(model)
    p[:, 0] *= 1.2
    p[:, 1:] *= 1.2
    path = lg.save(tmp_path / "lg.json", lg.LeaderGravity(arm.name, arm.sha256, p, {}, {}))
    np.testing.assert_allclose(lg.load(path, arm), p)
    g_fn, _ = arm_model_fns(arm, gravity_file=path)
    g_desc, _ = arm_model_fns(arm)
    np.testing.assert_allclose(g_fn(arm.q_home), 1.2 * g_desc(arm.q_home), rtol=1e-9, atol=1e-12)
    with pytest.raises(ConfigError, match="not on 'gello_yam'"):
        lg.load(path, load_arm("gello_yam"))
    bad = p.copy()
    bad[0, 0] = -1.0
    with pytest.raises(ConfigError):
        lg.model_with_params(model, bad)
    (tmp_path / "junk.json").write_text("{")
    with pytest.raises(ConfigError, match="cannot read"):
        lg.load(tmp_path / "junk.json", arm)


def test_identification_on_the_twin_leader_lowers_the_rest_residual():
    from hardware.connect import open_rig

    arm = load_arm("gello_piper")
    fast = lg.HoldGains(move_s=0.5, settle_s=0.7, measure_s=0.2)
    with open_rig("sim-piper", clock="lockstep", seed=0) as s:
        res = lg.identify(s.leader, s.clock, arm, n_fit=6, n_check=3, gains=fast, rate_hz=200.0)
    assert res.meta["poses_fit"] >= 4 and res.meta["poses_check"] >= 2
    # the twin's GELLO has horns, a heavier handle and other printed masses than its description
    assert res.before["rms_mean_nm"] > 0.01
    assert res.after["rms_mean_nm"] < 0.5 * res.before["rms_mean_nm"]


def test_cli_bad_input_is_one_line_and_exit_2(capsys):
    from factr2_teleop.cli import main

    assert main(["leader-gravity", "--rig", "sim-piper", "--leader", "nope"]) == 2
    assert main(["leader-gravity", "--rig", "no-such-rig"]) == 2
    assert main(["leader-gravity", "--rig", "sim-piper", "--poses", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "Traceback" not in "".join(err)


def test_what_gravity_never_sees_stays_as_described(gello):
    """A fit's parameters mapped back (gravity_null_space, described_where_unidentified): the same gravity
    at every pose, and a mass the holds cannot see (J1 turns about the vertical: link 1's mass) is the
    description's -- a fit that moved it to -1 kg (what `factr2 leader-gravity` refused) is repaired."""
    arm, model = gello
    lim = arm.limits
    null = lg.gravity_null_space(model, lim.q_min, lim.q_max)
    p0 = lg.description_params(model)
    assert 0 < null.shape[1] < p0.size
    fit = p0 * 1.1
    fit[0, 0] = -1.0  # link 1's mass: gravity never sees it
    mapped = lg.described_where_unidentified(fit, p0, null)
    assert mapped[0, 0] == pytest.approx(p0[0, 0]) and np.all(mapped[:, 0] > 0)
    Q = lg.hold_poses(lim.q_min, lim.q_max, 8, seed=3)
    Y = lg.gravity_regressor(model, Q)
    np.testing.assert_allclose(Y @ mapped.reshape(-1), Y @ fit.reshape(-1), atol=1e-10)
    lg.model_with_params(model, mapped)  # accepted
