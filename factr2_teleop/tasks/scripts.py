"""Scripted demonstrations, one generator per task, driving an Operator (operator.py) one decision per yield.

A script reads op.p (the Percept: follower pose and task objects as seen, the feedback felt) and sets the
operator's targets. It behaves like a person: per-episode speed and per-move jitter, a curved path, an
approach that sometimes arrives misaligned (noise on where it thinks the target is), contact felt through the
leader's force feedback, then backing off and realigning. Its result (returned by the generator) is a dict:
{"gave_up": bool, "retries": int, "felt": [...]}; success is decided by the task's detectors, not here.
Primitives here; the pick-and-insert scripts (peg-insert, press-fit) in place.py, wiping in wipe.py; SCRIPTS
(factr2_teleop.tasks) maps task names to them.
"""

from __future__ import annotations

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.operator import DECIDE_EVERY, interp_pose, min_jerk

DECIDE_DT_S = DECIDE_EVERY / 500.0  # s: one decision (the loop runs at 500 Hz)
FELT_NM = 0.15  # N*m: ||feedback torque||_1 on the leader a person notices as "it hit something"
SEE_KI = 0.8  # 1/s: how fast the operator nudges a held tool onto where they want it (visual correction)
SEE_MAX_M = 0.01  # m: the largest such nudge
SEE_DEADBAND_M = 0.00015  # m: an error this small is left alone
JOINT_RAD_S = 1.5  # rad/s: the fastest a joint of a joint-space move's reference moves (peak)


def wait(op, seconds: float):
    for _ in range(max(1, round(seconds / DECIDE_DT_S))):
        yield


def move(op, T_to, seconds: float, tool=None, bump=None, T_from=None, seen=None):
    """Move the gripper (tool None) or a held tool (tool(): T_ee_tool) to T_to over `seconds`. seen(): the
    tool's position as seen; given, the operator nudges the tool onto the path by what they see."""
    if T_from is None:
        T_from = op.ee_pose_des() if tool is None else op.ee_pose_des() @ tool()
        T_from[:2, 3] -= op.nudge
    n = max(1, round(seconds / DECIDE_DT_S))
    for k in range(1, n + 1):
        T = interp_pose(T_from, T_to, k / n, bump)
        aim_tool(op, T, tool, seen)
        yield


def aim_tool(op, T, tool=None, seen=None) -> None:
    """Aim the gripper (tool None) or the held tool at T, with the visual nudge (world xy)."""
    if seen is not None:  # slower than the joint lean under it (two integrators of one error would ring)
        e = T[:2, 3] - seen()[:2]
        # a deadband: no hunting on the arm's stiction
        e = np.where(np.abs(e) > SEE_DEADBAND_M, e - np.sign(e) * SEE_DEADBAND_M, 0.0)
        op.nudge = np.clip(op.nudge + SEE_KI * DECIDE_DT_S * e, -SEE_MAX_M, SEE_MAX_M)
    T = T.copy()
    T[:2, 3] += op.nudge
    op.aim(T if tool is None else T @ np.linalg.inv(tool()))


def joint_move_s(op, q_to, seconds: float) -> float:
    """At least `seconds`, and slow enough that no joint's min-jerk peak exceeds JOINT_RAD_S (a hand that
    whips the leader's wrist round makes its encoder jump: the pair holds the follower)."""
    return max(seconds, 1.875 * float(np.max(np.abs(np.asarray(q_to) - op.q_des))) / JOINT_RAD_S)


def go_joints(op, q_to, seconds: float):
    """Move the reference in joint space (min-jerk) to q_to [rad] over joint_move_s(seconds)."""
    q0 = op.q_des.copy()
    n = max(1, round(joint_move_s(op, q_to, seconds) / DECIDE_DT_S))
    for k in range(1, n + 1):
        op.q_des = q0 + min_jerk(k / n) * (np.asarray(q_to) - q0)
        yield


def grip(op, fraction: float, seconds: float):
    g0 = op.grip
    n = max(1, round(seconds / DECIDE_DT_S))
    for k in range(1, n + 1):
        op.grip = g0 + (fraction - g0) * k / n
        yield


def yaw_of(R: np.ndarray) -> float:
    return float(np.arctan2(R[1, 0], R[0, 0]))


def best_down_yaw(op, p, yaw: float, period: float) -> float:
    """Of yaw + k * period, the gripper yaw whose IK keeps the wrist (last joint) nearest its middle."""
    best, score = yaw, np.inf
    for k in range(-4, 5):
        y = yaw + k * period
        T = K.pose(K.down_rotation(y), p)
        q, e = K.solve_ik(op.fk, op.jac, op.q_des, T, op.q_min, op.q_max, iters=30)
        s = abs(q[-1]) + 100.0 * np.linalg.norm(e[:3])
        if s < score:
            best, score = y, s
    return best


