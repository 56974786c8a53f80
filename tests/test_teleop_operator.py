"""Virtual operator (pure parts), estimators, and closed-loop feedback sign per joint on lockstep fakes."""

from __future__ import annotations

import numpy as np
import pytest
from teleop_fakes import N, Rig
from test_teleop_loop import fb_cfg

from calibration.estimators import (
    EstimatorInput,
    GroundTruthEstimator,
    MomentumObserver,
    PositionPositionEstimator,
)
from factr2_teleop.teleop.loop import TeleopLoop
from factr2_teleop.teleop.virtual_operator import (
    OperatorScript,
    Segment,
    VirtualOperator,
    hand_torque,
    make_task_script,
    min_jerk,
    scripted_target,
)
from hardware.types import JointState


def test_script_is_smooth_and_hits_keyframes():
    s = make_task_script(q_home=[0, 0, 0], q_above=[0.3, 0.2, 0], q_press=[0.3, 0.5, 0],
                         wipe_amp_rad=[0.2, 0, 0],
                         free_s=2.0, reach_s=1.0, contact_s=1.0, wipe_s=2.0, release_s=1.0)
    assert s.duration_s == pytest.approx(7.0)
    phases = [scripted_target(t, s)[2] for t in (0.5, 2.5, 3.5, 5.0, 6.2, 6.9)]
    assert phases == ["free", "reach", "contact", "wipe", "release", "release"]
    assert np.allclose(scripted_target(3.0, s)[0], [0.3, 0.2, 0.0])  # end of reach
    assert np.allclose(scripted_target(4.0, s)[0], [0.3, 0.5, 0.0])  # end of contact
    assert np.allclose(scripted_target(7.0, s)[0], [0, 0, 0]) and np.allclose(scripted_target(9.0, s)[0], 0)
    dt = 0.002
    ts = np.arange(0, 7.0, dt)
    q = np.array([scripted_target(t, s)[0] for t in ts])
    v = np.diff(q, axis=0) / dt
    assert np.max(np.abs(np.diff(v, axis=0))) < 0.04  # no velocity jumps between segments
    qd = np.array([scripted_target(t, s)[1] for t in ts[1:-1:10]])
    assert np.allclose(qd, ((q[2:] - q[:-2]) / (2 * dt))[::10], atol=5e-3)
    assert min_jerk(0) == 0 and min_jerk(1) == 1 and min_jerk(0.5) == pytest.approx(0.5)


def test_hand_impedance_and_log():
    tau = hand_torque(np.zeros(2), np.zeros(2), np.array([0.5, -2.0]), np.zeros(2), np.full(2, 3.0),
                      np.full(2, 0.1), np.full(2, 2.0))
    assert np.allclose(tau, [1.5, -2.0])  # second joint clipped to what a hand pushes
    s = OperatorScript(q_start=np.zeros(2), segments=[Segment("contact", 1.0, np.array([0.0, 1.0]))])
    op = VirtualOperator(s, stiffness=2.0, damping=0.0,
                         jacobian_fn=lambda q: np.vstack([np.eye(2), np.zeros((4, 2))]),
                         surface_normal=np.array([0.0, -1.0, 0.0]))
    t = op.torque(1.0, np.array([0.0, 0.8]), np.zeros(2))
    assert np.allclose(t, [0.0, 0.4])
    smp = op.log[-1]
    assert smp.press_nm == pytest.approx(0.4) and smp.force_n == pytest.approx(0.4)
    summ = op.summary()
    assert summ["contact"]["tau_l1_nm"] == pytest.approx(0.4)
    assert summ["contact"]["track_err_rad"] == pytest.approx(0.2)


def _state(q, qd, tau_m, t):
    n = len(q)
    return JointState(t=t, q=np.asarray(q, float), q_dot=np.asarray(qd, float),
                      tau_m=np.asarray(tau_m, float),
                      current=np.zeros(n), q_cmd=np.zeros(n), temperature=np.zeros(n),
                      status=np.zeros(n, dtype=np.uint32))


def test_estimators_convention():
    st = _state([0.1, 0.0], [0, 0], [0, 0], 2.0)
    pp = PositionPositionEstimator([10.0, 5.0], 2)
    e = pp.update(EstimatorInput(t=2.0, follower=st, q_leader_f=np.array([0.3, -0.1])))
    # follower behind the leader (blocked): its motors push toward the leader, against the obstacle
    assert np.allclose(e.tau_ext, [2.0, -0.5]) and e.t == 2.0 and e.valid
    inp = EstimatorInput(t=2.0, follower=st, q_leader_f=np.zeros(2))
    assert pp.refresh(inp) is None and pp.idle() is None and pp.period_s == 0.0  # the protocol's defaults
    g = GroundTruthEstimator(lambda: np.array([0.5, 0.0]))
    assert np.allclose(g.update(inp).tau_ext, [0.5, 0])


def test_momentum_observer_converges_to_environment_torque():
    """Pinocchio arm held still by its motors against gravity and a push: the DO finds the push."""
    import pinocchio as pin

    model = pin.buildSampleModelManipulator()
    obs = MomentumObserver.from_pinocchio(model, k_o=50.0)
    data = model.createData()
    q = np.array([0.2, -0.5, 0.4, 0.1, 0.3, -0.2])
    tau_env = np.array([0.5, -1.0, 0.3, 0.0, 0.2, -0.1])
    g = pin.computeGeneralizedGravity(model, data, q)
    est = None
    for k in range(300):  # 0.3 s at 1 kHz, statics: motors cancel gravity and the push
        est = obs.update(EstimatorInput(t=k * 1e-3, follower=_state(q, np.zeros(6), g - tau_env, k * 1e-3),
                                 q_leader_f=q))
    assert np.allclose(est.tau_ext, -tau_env, atol=1e-3)  # tau_ext = tau_m - tau_free = -tau_env


@pytest.mark.parametrize("joint", range(N))
def test_closed_loop_feedback_opposes_the_operator_per_joint(joint):
    """A hand pushes leader joint `joint` toward +0.6 rad; a wall stops the follower's joint at +0.2 rad.
    With ground-truth feedback the leader torque on that joint is negative (against the hand), the other
    joints get none, the leader stops short of the hand's target, and the hand pushes harder than without
    feedback (it feels the wall)."""
    results = {}
    for with_fb in (False, True):
        rig = Rig()
        target = np.zeros(N)
        target[joint] = 0.6
        script = OperatorScript(q_start=np.zeros(N), segments=[Segment("contact", 1.0, target),
                                                               Segment("contact", 1.0, target)])
        op = VirtualOperator(script, stiffness=1.0, damping=0.05, tau_max_nm=2.0)
        rig.hand = op.torque
        rig.wall = (joint, 0.2, +1, 20.0)  # N*m/rad, softer than the follower's position loop
        est = GroundTruthEstimator(rig.follower_tau_ext) if with_fb else None
        cfg = fb_cfg()
        cfg.soft_start.rate_limit_rad_s = 5.0
        cfg.law.feedback.gain, cfg.law.damping_kd = 0.1, 0.05
        loop = TeleopLoop([rig.pair(cfg, estimator=est)], rig.clock)
        recs = []
        loop.recorder = recs.append
        loop.run(duration_s=2.0)
        last = recs[-1]
        results[with_fb] = (rig.lb.q[joint], op.summary()["contact"]["tau_l1_nm"], last)
    q_nofb, push_nofb, _ = results[False]
    q_fb, push_fb, last = results[True]
    tau_fb = last.tau_feedback
    assert last.contact and last.gate == 1.0
    assert tau_fb[joint] < -0.1 and np.allclose(np.delete(tau_fb, joint), 0.0)
    assert q_nofb > 0.55 and q_fb < q_nofb - 0.1
    assert push_fb > push_nofb


def test_make_estimator_modes():
    from calibration.estimators import make_estimator
    from hardware.errors import ConfigError

    assert make_estimator("none", 3) is None
    assert isinstance(make_estimator("pp", 3, pp_stiffness_nm_per_rad=5.0), PositionPositionEstimator)
    assert isinstance(make_estimator("dob", 6, follower_arm="piper"), MomentumObserver)
    for mode in ("dob", "next", "ground_truth", "magic"):
        with pytest.raises(ConfigError):
            make_estimator(mode, 3)


def test_next_adapter_warmup_valid_and_nan():
    """NextAdapter over a stand-in with NextEstimator's update() contract (the real one needs a
    checkpoint)."""
    from calibration.estimate import FLAG_NONFINITE, FLAG_OOD, FLAG_WARMUP, Estimate
    from calibration.estimators import NextAdapter, make_estimator

    class Stand:
        def __init__(self):
            self.calls = []

        def update(self, q, q_dot, q_cmd, tau_m, temperature=None):
            self.calls.append(np.array(q_cmd))
            k = len(self.calls)
            if k < 3:  # warm-up
                return Estimate(np.full(2, np.nan), flags=FLAG_WARMUP)
            if k == 5:  # a bad sample: NaN, passed on (the gate turns feedback off with a message)
                return Estimate(np.full(2, np.nan), flags=FLAG_NONFINITE)
            return Estimate(np.array([0.5, -0.2]), flags=FLAG_OOD * (k == 4), tau_f=np.zeros(2))

        def work(self):
            pass

    stand = Stand()
    ad = make_estimator("next", 2, next_estimator=stand)
    assert isinstance(ad, NextAdapter)
    st = _state([0.1, 0.2], [0, 0], [1.0, 1.0], 3.0)
    st.q_cmd = np.array([np.nan, np.nan])
    inp = EstimatorInput(t=3.0, follower=st, q_leader_f=np.zeros(2), q_target_f=np.array([0.3, 0.4]))
    assert ad.update(inp) is None and ad.update(inp) is None
    e = ad.update(inp)
    assert np.allclose(e.tau_ext, [0.5, -0.2]) and e.valid and e.t == 3.0
    assert np.allclose(stand.calls[-1], [0.3, 0.4])  # no reported q_cmd: the loop's last target
    st.q_cmd = np.array([0.11, 0.21])
    ad.update(inp)
    assert np.allclose(stand.calls[-1], [0.11, 0.21]) and ad.ood_count == 1
    e = ad.update(inp)
    assert np.all(np.isnan(e.tau_ext)) and not e.valid
