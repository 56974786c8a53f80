"""The scripted operator's pure pieces: IK on the Piper description, pose interpolation, hand and lean."""

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.operator import (
    HAND_TAU_MAX,
    SERVO_MAX_RAD,
    hand_torque,
    interp_pose,
    servo_update,
    trigger_torque,
)


def test_ik_reaches_top_down_poses_on_the_piper():
    from hardware.arms import load_arm
    from hardware.arms.dynamics import ArmDynamics

    arm = load_arm("piper")
    dyn, lim = ArmDynamics(arm), arm.limits
    for p, yaw in (((0.27, -0.12, 0.05), 0.3), ((0.30, 0.11, 0.06), 1.0), ((0.30, 0.0, 0.02), 0.0)):
        T = K.pose(K.down_rotation(yaw), p)
        q, e = K.solve_ik(dyn.fk, dyn.jacobian, np.array(arm.q_home), T, lim.q_min, lim.q_max)
        assert np.abs(e[:3]).max() < 1e-4 and np.abs(e[3:]).max() < 1e-3
        assert np.all(q >= lim.q_min) and np.all(q <= lim.q_max)
        assert np.allclose(dyn.fk(q)[:3, 2], [0, 0, -1], atol=1e-3)  # the approach axis points down


def test_rotations_and_interpolation():
    R = K.down_rotation(0.4)
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(K.rotation_error(R, R), 0.0)
    Rz = K.down_rotation(0.0).T @ K.down_rotation(0.3)
    assert np.isclose(np.linalg.norm(K.rotation_error(np.eye(3), Rz)), 0.3)
    T0, T1 = K.pose(K.down_rotation(0.0), [0.2, 0, 0.1]), K.pose(K.down_rotation(0.5), [0.3, 0.1, 0.05])
    assert np.allclose(interp_pose(T0, T1, 0.0), T0) and np.allclose(interp_pose(T0, T1, 1.0), T1)
    mid = interp_pose(T0, T1, 0.5, bump=[0, 0, 0.02])
    assert np.allclose(mid[:3, 3], [0.25, 0.05, 0.095])  # half way (min-jerk) plus the full bump


def test_hand_lean_and_trigger_are_bounded():
    tau = hand_torque(np.zeros(6), np.zeros(6), np.full(6, 5.0), np.zeros(6))
    assert np.allclose(tau, HAND_TAU_MAX)
    assert np.allclose(hand_torque(np.full(6, np.nan), np.zeros(6), np.zeros(6), np.zeros(6)), 0.0)
    b = np.zeros(6)
    for _ in range(10_000):
        b = servo_update(b, np.ones(6), np.zeros(6), 0.01)
    assert np.allclose(b, SERVO_MAX_RAD)
    assert trigger_torque(0.0, 1.0) > 0 > trigger_torque(1.0, 0.0)
    assert trigger_torque(float("nan"), 0.0) == 0.0


class _ReachedTouchDown(Exception):
    pass


class _Blind:
    """A percept stub: the wipe script reads what it sees first at its touch-down, where the replay stops."""

    @property
    def obs(self):
        raise _ReachedTouchDown


def test_wipe_approach_of_seed_5603_reaches_the_mark_not_a_wrong_ik_branch():
    """Collection seed 5603's episode 0 (episode seed 560316809): the warm-started IK slid onto a wrong
    branch (base -2.3 rad, shoulder pinned at its limit, 0.4 m from the mark) and the collection scored
    0 / 25. The approach is replayed on the description with the follower tracking q_des exactly."""
    from factr2_teleop.tasks import wipe as WS
    from factr2_teleop.tasks.operator import Operator
    from hardware.arms import load_arm
    from hardware.arms.dynamics import ArmDynamics
    from hardware.sim.tasks import wipe as W

    arm = load_arm("piper")
    dyn, lim = ArmDynamics(arm), arm.limits
    for seed in (560316809, 560116803, 560216806):
        rng = np.random.default_rng(seed)  # the task's reset draws first (hardware/sim/tasks/wipe.py)
        params = {"area_pos": np.array([rng.uniform(*W.AREA_X), rng.uniform(*W.AREA_Y), 0.0]),
                  "area_yaw": rng.uniform(*W.AREA_YAW)}
        op = Operator(dyn.fk, dyn.jacobian, lim.q_min, lim.q_max, lambda q: q, 0.002,
                      q_start=[0, 0, 0, 0, 0.033, 0])
        op.p = _Blind()
        script = WS.wipe(op, params, rng)
        try:
            while True:
                next(script)
        except _ReachedTouchDown:
            pass
        tip = dyn.fk(op.q_des)[:3, 3]
        mark = np.asarray(params["area_pos"])
        assert np.linalg.norm(tip[:2] - mark[:2]) < 0.06, (seed, tip, op.q_des)  # over the mark (+-34 mm)
        assert 0.03 < tip[2] < 0.08, (seed, tip)  # 4 cm above it, ready to touch down


def test_aim_computes_each_forward_kinematics_once_and_returns_the_residual_of_its_joints():
    """Operator.aim takes the residual [m] from aim_joints (the FK of the joints it chose), not a second FK;
    the residual is exactly that of the joints returned, on the warm-started and the re-solved branch."""
    from factr2_teleop.tasks.operator import AIM_BRANCH_M, Operator, aim_joints
    from hardware.arms import load_arm
    from hardware.arms.dynamics import ArmDynamics

    arm = load_arm("piper")
    dyn, lim = ArmDynamics(arm), arm.limits
    calls = []

    def fk(q):
        calls.append(1)
        return dyn.fk(q)

    T = K.pose(K.down_rotation(0.3), (0.27, -0.12, 0.05))
    rng = np.random.default_rng(0)
    branches = set()
    for q_from in [np.array(arm.q_home, float), lim.q_min + 0.02, *rng.uniform(lim.q_min, lim.q_max, (4, 6))]:
        for iters in (1, 4):
            q, res = aim_joints(dyn.fk, dyn.jacobian, q_from, T, lim.q_min, lim.q_max, iters)
            assert res == float(np.linalg.norm(K.pose_error(dyn.fk(q), T)[:3]))
            warm = np.asarray(q_from, float)
            for _ in range(iters):
                warm = K.ik_step(dyn.fk, dyn.jacobian, warm, T, lim.q_min, lim.q_max)
            branches.add(bool(np.any(q != warm)))
            op = Operator(fk, dyn.jacobian, lim.q_min, lim.q_max, lambda x: x, 0.002, q_start=q_from)
            calls.clear()
            assert op.aim(T, iters) == res
            resolved = float(np.linalg.norm(K.pose_error(dyn.fk(warm), T)[:3])) > AIM_BRANCH_M
            if not resolved:
                assert len(calls) == iters + 1  # one FK per IK step and one for the residual
    assert branches == {False, True}  # both branches were exercised
