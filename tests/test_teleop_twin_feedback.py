"""SIMULATED, on the sim-piper twin (real wire protocols, lockstep): pushing the follower makes the leader
push back against the operator, on each joint.

A stiff virtual hand holds the leader at its start pose; the follower is pushed (forces and torques on its
last link, one at a time). Project convention: tau_ext = tau_m - tau_free = minus the environment's torque
on the follower. Expected per joint j with a real push torque tau_env_j: the leader's feedback torque has
the sign of tau_env_j (the leader is driven the way the follower is pushed), and the hand holding the leader
ends up pushing the other way (the operator feels the push).
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration.estimators import make_estimator
from factr2_teleop.teleop.leader_law import arm_model_fns
from factr2_teleop.teleop.pair import COUPLED, ArmPair, PairConfig
from factr2_teleop.teleop.virtual_operator import OperatorScript, Segment, VirtualOperator
from hardware.connect import open_rig

RATE = 250.0  # Hz: half the demo rate keeps the test fast; the laws are rate-independent
GAINS = [0.06, 0.08, 0.08, 0.03, 0.03, 0.02]
PUSHES = [  # (force N, torque N*m) on link6, world frame
    ([0.0, 25.0, 0.0], None),
    ([0.0, 0.0, -25.0], None),
    ([0.0, 0.0, 0.0], [3.0, 0.0, 0.0]),
    ([0.0, 0.0, 0.0], [0.0, 3.0, 0.0]),
    ([0.0, 0.0, 0.0], [0.0, 0.0, 3.0]),
]
PUSH_S, SETTLE_S = 0.4, 0.3
AT_STOP_RAD = 0.01  # rad: a leader joint this close to its range limit is against its end stop


@pytest.fixture()
def twin_pair():
    s = open_rig("sim-piper", clock="lockstep", seed=0)
    try:
        lead, fol = s.pairs[0]
        g, jac = arm_model_fns(s.rig.leaders[0].arm)
        cfg = PairConfig(name="arm")
        cfg.law.feedback.gain, cfg.law.feedback.clip_nm = GAINS, 1.0
        cfg.law.feedback.t_high_nm, cfg.law.feedback.t_low_nm = 1.0, 0.5
        world = s.twin.devices["follower"].world
        est = make_estimator("ground_truth", fol.n_joints, truth=lambda: world.ground_truth()[0].tau_ext)
        pair = ArmPair(lead, fol, cfg, 1 / RATE, gravity_fn=g, jacobian_fn=jac, estimator=est)
        yield s, pair, world
    finally:
        s.close()


def test_pushing_the_follower_makes_the_leader_push_back_on_each_joint(twin_pair):
    s, pair, world = twin_pair
    lead = pair.leader
    q0 = lead.read().q
    lim = lead.safety.limits
    hand = VirtualOperator(OperatorScript(q0, [Segment("free", 100.0, q0)]), stiffness=8.0, damping=0.2,
                           tau_max_nm=3.0, t0=s.clock.now())
    rows = []

    def on_tick(rec):
        st = lead.last_state
        tau_h = hand.torque(rec.t, st.q, np.nan_to_num(st.q_dot))
        s.twin.apply_leader_hand_torque(tau_h)
        gt = world.ground_truth()[0]
        rows.append((rec.phase, rec.tau_feedback, -gt.tau_push[:6], tau_h, st.q.copy()))

    def run(seconds):  # the loop's tick sequence, kept running across pushes (TeleopLoop.run ends safe)
        for _ in range(round(seconds * RATE)):
            on_tick(pair.tick(s.clock.now()))
            s.clock.sleep(1 / RATE)

    pair.begin()
    run(SETTLE_S)
    assert pair.phase == COUPLED
    covered: dict[int, int] = {}
    for force, torque in PUSHES:
        rows.clear()
        world.push("link6", np.asarray(force, float), PUSH_S,
                   torque=None if torque is None else np.asarray(torque, float))
        run(PUSH_S)
        late = rows[len(rows) // 2:]  # after the feedback ramp and the leader's response
        fb = np.mean([r[1] for r in late], axis=0)
        env = np.mean([r[2] for r in late], axis=0)
        tau_hand = np.mean([r[3] for r in late], axis=0)
        q_lead = np.mean([r[4] for r in late], axis=0)
        assert all(r[0] == COUPLED for r in late)
        for j in np.flatnonzero(np.abs(env) > 1.0):  # joints this push really loads [N*m]
            assert np.sign(fb[j]) == np.sign(env[j]), (force, torque, j, fb, env)
            assert abs(fb[j]) > 0.02
            # a leader joint driven into its end stop does not move: the stop takes the feedback and the
            # hand's torque there is ~0 with a sign set by rounding noise (it flipped on another CPU model)
            at_stop = abs(q_lead[j] - (lim.q_max[j] if fb[j] > 0 else lim.q_min[j])) < AT_STOP_RAD
            if at_stop:
                assert abs(tau_hand[j]) < 0.25 * abs(fb[j]), (force, torque, j, tau_hand, fb)
            elif abs(fb[j]) > 0.05:  # enough to move the held leader measurably
                assert np.sign(tau_hand[j]) == -np.sign(fb[j]), (force, torque, j, tau_hand, fb)
            covered[j] = covered.get(j, 0) + 1
        run(0.1)  # let go
    assert sorted(covered) == list(range(6)), covered
