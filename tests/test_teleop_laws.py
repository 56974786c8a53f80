"""Leader law terms, feedback gating and joint maps: pure functions, checked per joint."""

from __future__ import annotations

import numpy as np
import pytest

from factr2_teleop.teleop.feedback import (
    FeedbackConfig,
    FeedbackGate,
    contact_hysteresis,
    ema,
    estimate_fresh,
    feedback_torque,
    ramp_toward,
)
from factr2_teleop.teleop.leader_law import (
    LeaderInputs,
    LeaderLaw,
    LeaderLawConfig,
    cap_total,
    friction_coulomb,
    friction_dither,
    joint_limit_barrier,
    null_space_projector,
    null_space_term,
    pinocchio_gravity,
    pinocchio_jacobian,
)
from factr2_teleop.teleop.mapping import JointMap, JointMapConfig
from hardware.errors import ConfigError
from hardware.types import JointLimits

N = 4


def lim(n=N, tau_max=3.0):
    return JointLimits(q_min=np.full(n, -1.5), q_max=np.full(n, 1.5), v_max=np.full(n, 5.0),
                       tau_max=np.full(n, tau_max), tau_rate_max=np.full(n, 100.0))


def only_feedback_cfg(**fb) -> LeaderLawConfig:
    cfg = LeaderLawConfig()
    cfg.gravity.enabled = False
    cfg.friction.mode = "off"
    cfg.barrier.enabled = False
    cfg.feedback = FeedbackConfig(**{"gain": 0.1, "ramp_in_s": 0.0, "ramp_out_s": 0.0, "clip_nm": 10.0, **fb})
    return cfg


@pytest.mark.parametrize("joint", range(N))
def test_feedback_opposes_operator_on_each_joint(joint):
    """Operator pushes leader joint i in +; the follower hits a wall, whose torque on follower joint i is
    negative; the leader torque on joint i must be negative (against the operator) and zero elsewhere.
    Holds through a mapping with a sign flip and an index permutation as well."""
    for mcfg in (JointMapConfig(), JointMapConfig(index=[1, 0, 3, 2], sign=[-1, 1, -1, 1], scale=1.5)):
        m = JointMap(mcfg, N, N)
        law = LeaderLaw(only_feedback_cfg(t_high_nm=0.5, t_low_nm=0.2), lim())
        # leader joint `joint` pushed +: which follower joint moves, in which direction?
        fj = int(np.flatnonzero(m.index == joint)[0])
        dq_f = m.forward_velocity(np.eye(N)[joint])[fj]  # follower joint velocity per leader velocity
        tau_wall_f = np.zeros(N)
        tau_wall_f[fj] = -np.sign(dq_f) * 2.0  # the wall opposes the follower's motion
        tau_l = m.torque_back(-tau_wall_f)  # tau_ext = tau_m - tau_free = -(wall on follower)
        out = law.step(LeaderInputs(t=1.0, q=np.zeros(N), q_dot=np.eye(N)[joint] * 0.1, tau_ext_leader=tau_l,
                                    contact_score_nm=2.0, est_t=1.0, est_fresh=True))
        assert out.tau[joint] < -0.05, (mcfg, out.tau)
        assert np.allclose(np.delete(out.tau, joint), 0.0)
        # and the push power is negative: the leader resists the operator's motion
        assert out.tau @ (np.eye(N)[joint]) < 0


def test_contact_hysteresis():
    seq = [0.2, 0.8, 1.2, 0.8, 0.6, 0.4, 0.8]
    state, states = False, []
    for s in seq:
        state = contact_hysteresis(s, state, t_high=1.0, t_low=0.5)
        states.append(state)
    assert states == [False, False, True, True, True, False, False]


def test_gate_follows_hysteresis_and_ramps_in_and_out():
    cfg = FeedbackConfig(gain=1.0, clip_nm=10.0, t_high_nm=1.0, t_low_nm=0.5, ramp_in_s=0.1, ramp_out_s=0.05)
    g = FeedbackGate(cfg, 2)
    dt, t = 0.002, 0.0
    tau = np.array([0.4, 0.4])  # score 0.8: between thresholds, no contact yet
    for _ in range(10):
        t += dt
        r = g.step(t, tau, 0.8, t, True)
    assert r.gate == 0.0 and not r.contact
    tau = np.array([1.0, 1.0])  # score 2: contact, ramps in over 0.1 s
    gates = []
    for _ in range(60):
        t += dt
        gates.append(g.step(t, tau, 2.0, t, True).gate)
    assert gates[0] == pytest.approx(0.02) and gates[24] == pytest.approx(0.5) and gates[-1] == 1.0
    assert np.all(np.diff(gates) >= 0)
    # drop to 0.8 (between thresholds): still in contact
    t += dt
    assert g.step(t, tau * 0.4, 0.8, t, True).contact
    # below t_low: ramps out over 0.05 s
    outs = []
    for _ in range(30):
        t += dt
        outs.append(g.step(t, np.array([0.1, 0.1]), 0.2, t, True).gate)
    assert outs[0] == pytest.approx(1 - 0.04) and outs[24] == 0.0


def test_staleness_gates_feedback_and_ramps_out_the_last_value():
    cfg = FeedbackConfig(gain=1.0, clip_nm=10.0, t_high_nm=0.5, t_low_nm=0.2, max_age_s=0.1, ramp_in_s=0.0,
                         ramp_out_s=0.02)
    g = FeedbackGate(cfg, 1)
    r = g.step(1.0, np.array([2.0]), 2.0, 1.0, True)
    assert r.gate == 1.0 and r.tau_fb[0] == pytest.approx(-2.0)
    # the estimate stops updating (same t_est): fresh until 0.1 s old, then ramps out over 0.02 s
    r = g.step(1.09, np.array([2.0]), 2.0, 1.0, True)
    assert r.fresh and r.gate == 1.0
    r = g.step(1.11, np.array([5.0]), 5.0, 1.0, True)  # stale: the new value is not used
    assert not r.fresh and r.gate == pytest.approx(0.0) and r.tau_fb[0] == pytest.approx(0.0)
    g2 = FeedbackGate(cfg, 1)
    g2.step(1.0, np.array([2.0]), 2.0, 1.0, True)
    r = g2.step(1.005, np.array([9.0]), 9.0, 1.005, False)  # the source says not fresh
    assert not r.fresh and r.gate == pytest.approx(0.75) and r.tau_fb[0] == pytest.approx(-1.5)
    assert estimate_fresh(1.0, 0.95, 0.1) and not estimate_fresh(1.0, 0.85, 0.1)
    assert not estimate_fresh(1.0, float("nan"), 0.1) and not estimate_fresh(1.0, 1.0, 0.1, False)


def test_nan_estimate_turns_feedback_off_with_message():
    cfg = FeedbackConfig(gain=1.0, clip_nm=10.0, t_high_nm=0.5, t_low_nm=0.2, ramp_in_s=0.0, ramp_out_s=1.0)
    g = FeedbackGate(cfg, 3)
    assert g.step(0.0, np.ones(3), 3.0, 0.0, True).gate == 1.0
    r = g.step(0.002, np.array([1.0, np.nan, 1.0]), float("nan"), 0.002, True)
    assert r.gate == 0.0 and np.all(r.tau_fb == 0.0) and "non-finite" in r.message and "[1]" in r.message
    assert g.nan_events == 1
    r = g.step(0.004, np.array([1.0, np.nan, 1.0]), float("nan"), 0.004, True)
    assert r.gate == 0.0 and r.message is None and g.nan_events == 2  # said once
    r = g.step(0.006, np.ones(3), 3.0, 0.006, True)
    assert "finite again" in r.message and r.gate == 1.0  # back on through the ramp (ramp_in_s = 0)


def test_ramp_clip_and_total_cap():
    assert ramp_toward(0.0, 1.0, 0.01, 0.1, 0.2) == pytest.approx(0.1)
    assert ramp_toward(1.0, 0.0, 0.01, 0.1, 0.2) == pytest.approx(0.95)
    assert ramp_toward(0.99, 1.0, 0.01, 0.1, 0.2) == 1.0
    assert ramp_toward(0.3, 1.0, 0.01, 0.0, 0.2) == 1.0
    tau = feedback_torque(np.array([10.0, -10.0, 1.0]), np.array([0.1, 0.1, 0.1]), 1.0,
                          np.array([0.5, 2.0, 2.0]))
    assert np.allclose(tau, [-0.5, 1.0, -0.1])
    out, n = cap_total(np.array([3.0, -3.0, 0.2]), np.array([1.0, 2.0, 1.0]))
    assert np.allclose(out, [1.0, -2.0, 0.2]) and n == 2
    # the law caps the sum per joint
    cfg = only_feedback_cfg(gain=1.0, t_high_nm=0.1, t_low_nm=0.0, clip_nm=5.0)
    cfg.damping_kd = 1.0
    cfg.tau_total_max_nm = [0.3, 1.0, 1.0, 1.0]
    law = LeaderLaw(cfg, lim())
    out = law.step(LeaderInputs(t=0.0, q=np.zeros(N), q_dot=np.array([2.0, 0, 0, 0]),
                                tau_ext_leader=np.array([1.0, 0.5, 0, 0]), contact_score_nm=1.5, est_t=0.0,
                                est_fresh=True))
    assert np.allclose(out.terms["feedback"], [-1.0, -0.5, 0, 0])
    assert np.allclose(out.terms["damping"], [-2, 0, 0, 0])
    assert np.allclose(out.tau, [-0.3, -0.5, 0, 0]) and out.capped == 1


def test_gravity_term_equals_gain_times_g_through_model_frame():
    g_model = np.array([0.3, -0.2, 0.1, 0.05])
    calls = []

    def gfun(qm):
        calls.append(qm.copy())
        return g_model

    cfg = LeaderLawConfig()
    cfg.gravity.gain = [0.85, 1.1, 1.0, 0.5]
    cfg.friction.mode = "off"
    cfg.barrier.enabled = False
    law = LeaderLaw(cfg, lim(), gravity_fn=gfun)
    out = law.step(LeaderInputs(t=0.0, q=np.full(N, 0.2), q_dot=np.zeros(N)))
    assert np.allclose(out.terms["gravity"], np.array([0.85, 1.1, 1.0, 0.5]) * g_model)
    assert np.allclose(out.tau, out.terms["gravity"])
    # a model frame with a flipped joint 1 and an offset: q converted forward, torques mapped back
    mm = JointMap(JointMapConfig(sign=[1, -1, 1, 1], offset_rad=[0, 0.5, 0, 0]), N, N)
    law = LeaderLaw(cfg, lim(), gravity_fn=gfun, model_map=mm)
    out = law.step(LeaderInputs(t=0.0, q=np.full(N, 0.2), q_dot=np.zeros(N)))
    assert np.allclose(calls[-1], [0.2, 0.3, 0.2, 0.2])
    assert np.allclose(out.terms["gravity"], np.array([0.85, -1.1, 1.0, 0.5]) * g_model)


def test_gravity_on_a_pinocchio_model_matches_rnea():
    import pinocchio as pin

    model = pin.buildSampleModelManipulator()
    model.gravity.linear = np.array([0, 0, -9.81])
    g = pinocchio_gravity(model)
    q = np.array([0.1, -0.4, 0.7, 0.2, -0.3, 0.5])
    ref = pin.rnea(model, model.createData(), q, np.zeros(6), np.zeros(6))
    assert np.allclose(g(q), ref) and np.linalg.norm(ref) > 0.1
    J = pinocchio_jacobian(model, "effector_body")(q)
    assert J.shape == (6, 6)
    with pytest.raises(ConfigError):
        pinocchio_jacobian(model, "nope")


def test_friction_dither_and_coulomb():
    g = np.array([1.0, -0.5, 0.0])
    qd = np.array([0.1, 2.0, 0.0])
    gain, mn, v = np.full(3, 0.6), np.array([0.0, 0.0, 0.05]), np.full(3, 0.9)
    tau, sign = friction_dither(g, qd, gain, mn, v, np.ones(3))
    assert np.allclose(tau, [0.6, 0.0, 0.05]) and np.all(sign == -1)
    tau2, sign2 = friction_dither(g, qd, gain, mn, v, sign)
    assert np.allclose(tau2, -tau) and np.all(sign2 == 1)
    c = friction_coulomb(np.array([0.5, -0.5, 0.01]), np.full(3, 0.2), np.full(3, 0.1))
    assert np.allclose(c, [0.2, -0.2, 0.0])


def test_barrier_only_outside_margin_and_pushes_inward():
    qmin, qmax = np.full(3, -1.0), np.full(3, 1.0)
    m, kp, kd = np.full(3, 0.1), np.full(3, 2.0), np.full(3, 0.5)
    q = np.array([0.85, 0.95, -0.95])
    tau = joint_limit_barrier(q, np.array([0.0, 0.2, -0.2]), qmin, qmax, m, kp, kd)
    assert tau[0] == 0.0
    assert tau[1] == pytest.approx(-2.0 * 0.05 - 0.5 * 0.2) and tau[1] < 0
    assert tau[2] == pytest.approx(2.0 * 0.05 + 0.5 * 0.2) and tau[2] > 0


def test_null_space_term_lies_in_the_null_space():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(6, 7))
    N_ = null_space_projector(J)
    assert np.allclose(J @ N_, 0.0, atol=1e-10)
    q, qd, q_ns = rng.normal(size=7), rng.normal(size=7), np.zeros(7)
    tau = null_space_term(q, qd, J, q_ns, np.full(7, 0.1), np.full(7, 0.01))
    assert np.linalg.norm(tau) > 1e-4 and np.allclose(J @ tau, 0.0, atol=1e-10)
    # through the law, with the posture taken at reset
    cfg = LeaderLawConfig()
    cfg.gravity.enabled, cfg.friction.mode, cfg.barrier.enabled = False, "off", False
    cfg.null_space.enabled = True
    law = LeaderLaw(cfg, lim(7), jacobian_fn=lambda qm: J)
    law.reset(q_ns)
    out = law.step(LeaderInputs(t=0.0, q=q, q_dot=qd))
    assert np.allclose(out.terms["null_space"], tau) and np.allclose(J @ out.tau, 0.0, atol=1e-10)
    with pytest.raises(ConfigError):
        LeaderLaw(cfg, lim(7))  # null space on without a Jacobian


def test_nan_model_output_never_reaches_the_leader():
    cfg = LeaderLawConfig()
    cfg.friction.mode = "off"
    law = LeaderLaw(cfg, lim(), gravity_fn=lambda q: np.full(N, np.nan))
    out = law.step(LeaderInputs(t=0.0, q=np.zeros(N), q_dot=np.zeros(N)))
    assert np.all(out.tau == 0.0)


def test_joint_map_forward_backward_and_virtual_work():
    m = JointMap(JointMapConfig(index=[2, 0, 1], sign=[1, -1, 1], scale=[1.0, 2.0, 0.5],
                                offset_rad=[0.1, 0.0, -0.2], gripper_scale=0.08, gripper_max=0.07), 4, 3)
    ql = np.array([0.3, -0.2, 0.5, 9.0])
    qf = m.forward(ql)
    assert np.allclose(qf, [0.5 + 0.1, -2 * 0.3, 0.5 * -0.2 - 0.2])
    back = m.backward(qf)
    assert np.allclose(back[:3], ql[:3]) and np.isnan(back[3])
    rng = np.random.default_rng(1)
    dql, tau_f = rng.normal(size=4), rng.normal(size=3)
    assert np.dot(m.torque_back(tau_f), dql) == pytest.approx(np.dot(tau_f, m.forward_velocity(dql)))
    assert m.gripper_forward(0.5) == pytest.approx(0.04) and m.gripper_forward(1.0) == pytest.approx(0.07)
    assert m.gripper_forward(float("nan")) is None
    for bad in (JointMapConfig(index=[0, 0, 1]), JointMapConfig(sign=[1, 0.5, 1]), JointMapConfig(scale=-1)):
        with pytest.raises(ConfigError):
            JointMap(bad, 4, 3)


def test_config_from_dict_and_bad_values():
    cfg = LeaderLawConfig.from_dict({"gravity": {"gain": [1.0, 1.1, 1.1, 1.2]}, "damping_kd": 0.01,
                                     "feedback": {"gain": 0.05, "t_high_nm": 2.0}})
    assert cfg.gravity.gain[3] == 1.2 and cfg.feedback.t_high_nm == 2.0
    with pytest.raises(ConfigError):
        LeaderLawConfig.from_dict({"gravity": {"gian": 1.0}})
    with pytest.raises(ConfigError):
        LeaderLaw(LeaderLawConfig(), lim())  # gravity on, no model
    bad = only_feedback_cfg(gain=[0.1, 0.1])
    with pytest.raises(ConfigError):
        LeaderLaw(bad, lim())
    with pytest.raises(ConfigError):
        LeaderLaw(only_feedback_cfg(t_high_nm=0.1, t_low_nm=0.5), lim())


def test_gripper_feedback_ema():
    assert ema(float("nan"), 2.0, 0.9) == 2.0 and ema(2.0, float("nan"), 0.9) == 2.0
    assert ema(1.0, 2.0, 0.9) == pytest.approx(1.1)
    g = FeedbackGate(FeedbackConfig(gripper_gain=0.1, gripper_ema_beta=0.5, gripper_clip_nm=0.3), 1)
    r = [g.step(i * 0.01, None, 0.0, 0.0, False, gripper_effort=4.0).gripper_tau for i in range(3)]
    assert r[0] == pytest.approx(0.3) and r[-1] == pytest.approx(0.3)  # 0.4 clipped to 0.3
    g = FeedbackGate(FeedbackConfig(gripper_gain=0.1, gripper_ema_beta=0.5), 1)
    g.step(0.0, None, 0.0, 0.0, False, gripper_effort=0.0)
    assert g.step(0.01, None, 0.0, 0.0, False, gripper_effort=2.0).gripper_tau == pytest.approx(0.1)


def test_law_on_the_shipped_leader_description():
    from factr2_teleop.teleop.leader_law import arm_model_fns
    from hardware.arms import load_arm
    from hardware.arms.dynamics import gravity

    arm = load_arm("gello_piper")
    g_fn, j_fn = arm_model_fns(arm)
    cfg = LeaderLawConfig()
    cfg.friction.mode = "off"
    law = LeaderLaw(cfg, arm.limits, gravity_fn=g_fn, jacobian_fn=j_fn)
    q = arm.q_home
    out = law.step(LeaderInputs(t=0.0, q=q, q_dot=np.zeros(arm.n_joints)))
    assert np.allclose(out.terms["gravity"], 0.85 * gravity(arm, q))
    assert np.abs(out.terms["gravity"]).max() > 0.1
    assert j_fn(q).shape == (6, arm.n_joints)


def test_pair_config_from_dict():
    from factr2_teleop.teleop.pair import PairConfig

    c = PairConfig.from_dict({"name": "left", "leader_stale_s": 0.01, "law": {"feedback": {"gain": 0.06}},
                              "mapping": {"sign": [1, -1, 1]}, "soft_start": {"max_mismatch_rad": 0.5}})
    assert c.name == "left" and c.law.feedback.gain == 0.06 and c.mapping.sign == [1, -1, 1]
    assert c.soft_start.max_mismatch_rad == 0.5 and c.leader_stale_s == 0.01
    with pytest.raises(ConfigError):
        PairConfig.from_dict({"mapping": {"signs": [1]}})
    with pytest.raises(ConfigError):
        PairConfig.from_dict({"rate": 3})
