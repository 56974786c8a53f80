"""A scripted operator that demonstrates through the LEADER (SIMULATED hand on the twin's GELLO leader).

The operator never touches the follower. Each tick it pushes the leader's joints and trigger with a hand
impedance toward a reference (hand_torque), exactly as the demo's virtual operator does; the teleop stack
(Dynamixel leader -> pair -> CAN follower, NEXT feedback) does the rest. What it decides from is what a person
has: the follower's pose and the task objects as seen (the twin's state, "vision", or with `--perception` the
simulated camera pose detector's report: seen.py), and the force feedback felt in the hand (the leader law's
feedback torque).

References. A script (a generator, see scripts.py) sets a Cartesian target for the gripper or for a held tool
(the peg); IK on the follower's description (kinematics.py) turns it into follower joints q_des. Because the
hand is compliant and the feedback pushes back, the leader (and so the follower) lags q_des; like a person who
watches the follower and pushes until it is where they want it, the operator integrates the follower's joint
error into its leader reference (servo term b, bounded), and maps that to leader joints through the pair's
joint map. Pure pieces (hand_torque, servo_update, interp_pose) are functions on arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from factr2_teleop.tasks import kinematics as K
from hardware.sim.perception import rotvec_exp

HAND_K = 8.0  # N*m/rad: a firm grip on a small leader (the demo's relaxed hand is 3)
HAND_D = 0.12  # N*m*s/rad
HAND_TAU_MAX = 2.0  # N*m per joint
TRIGGER_SPAN_RAD = 0.7  # leader trigger travel open -> closed (rig gripper_closed_rad - gripper_open_rad)
TRIGGER_K = 0.6  # N*m per unit of trigger fraction error
TRIGGER_TAU_MAX = 0.4  # N*m
SERVO_KI = 0.5  # 1/s: how fast the operator removes the follower's joint error
SERVO_MAX_RAD = 0.15  # rad: the most it leans into the leader beyond the reference
DECIDE_EVERY = 5  # ticks: the script decides (IK, vision) at 100 Hz on a 500 Hz loop
AIM_STEP_RAD = 0.03  # rad per joint and decision: the reference never jumps (no IK branch flips)
AIM_BRANCH_M = 0.03  # m: a warm-started IK this far from its target has slid onto a wrong branch (a joint
# pinned at its limit, the base turned away: wipe seed 5603); the aim then re-solves from the joints' middle


def hand_torque(q, qd, q_ref, qd_ref, k=HAND_K, d=HAND_D, tau_max=HAND_TAU_MAX) -> np.ndarray:
    """Joint-space hand impedance on the leader [N*m], clipped to what a hand pushes."""
    tau = k * (np.asarray(q_ref) - q) + d * (np.asarray(qd_ref) - np.nan_to_num(qd))
    return np.clip(np.where(np.isfinite(tau), tau, 0.0), -tau_max, tau_max)


def trigger_torque(fraction, fraction_ref) -> float:
    """Hand torque on the trigger [N*m] toward a closing fraction (0 open .. 1 closed)."""
    f = 0.0 if fraction is None or not np.isfinite(fraction) else float(fraction)
    return float(np.clip(TRIGGER_K * (fraction_ref - f), -TRIGGER_TAU_MAX, TRIGGER_TAU_MAX))


def servo_update(b, q_des, q_meas, dt, ki=SERVO_KI, limit=SERVO_MAX_RAD) -> np.ndarray:
    """Integrate the follower's joint error into the operator's lean b [rad] (bounded)."""
    return np.clip(b + ki * dt * (np.asarray(q_des) - np.asarray(q_meas)), -limit, limit)


def min_jerk(s: float) -> float:
    s = float(np.clip(s, 0.0, 1.0))
    return s ** 3 * (10.0 - 15.0 * s + 6.0 * s * s)


rodrigues = rotvec_exp  # rotation matrix of a rotation vector [rad] (one implementation, hardware's)


def interp_pose(T0: np.ndarray, T1: np.ndarray, s: float, bump=None) -> np.ndarray:
    """Min-jerk pose between T0 and T1 at s in [0, 1]; bump [m]: a sideways/upward excursion peaking mid-way
    (a person's path is not a straight line)."""
    a = min_jerk(s)
    p = T0[:3, 3] + a * (T1[:3, 3] - T0[:3, 3])
    if bump is not None:
        p = p + np.sin(np.pi * float(np.clip(s, 0, 1))) * np.asarray(bump)
    R = rodrigues(a * K.rotation_error(T0[:3, :3], T1[:3, :3])) @ T0[:3, :3]
    return K.pose(R, p)


def aim_joints(fk, jac, q_from, T_des, q_min, q_max, iters: int = 4) -> tuple[np.ndarray, float]:
    """(joints [rad] toward T_des, their position residual [m]): `iters` IK steps warm-started at q_from;
    when that is still over AIM_BRANCH_M from the target (a wrong branch: the damped steps, clipped at a
    limit, settle in a local minimum they never leave), a full solve from the middle of the joint ranges, if
    it lands nearer (the caller walks q_des there at AIM_STEP_RAD per decision, so the reference still never
    jumps). The residual is that of the joints returned (one FK each: solve_ik's is of its last q)."""
    q = np.asarray(q_from, float)
    for _ in range(iters):
        q = K.ik_step(fk, jac, q, T_des, q_min, q_max)
    res = float(np.linalg.norm(K.pose_error(fk(q), T_des)[:3]))
    if res > AIM_BRANCH_M:
        q_mid, e = K.solve_ik(fk, jac, (np.asarray(q_min) + np.asarray(q_max)) / 2, T_des, q_min, q_max)
        res_mid = float(np.linalg.norm(e[:3]))
        if res_mid < res:
            return q_mid, res_mid
    return q, res


@dataclass
class Percept:
    """What the operator has at a decision: t [s]; leader q/qd [rad, rad/s], trigger fraction; follower q
    [rad] (as reported); felt_nm: ||feedback torque on the leader||_1 [N*m]; T_ee: follower gripper pose seen
    (4x4, m); obs: the task's observe() arrays (with `factr2 collect --perception`: as seen, tasks/seen.py);
    seen: what the simulated camera pose detector reports now, name -> hardware.sim.perception.Seen (every
    collection fills it, for the tasks that name detectables: scripts that must not read the truth use only
    this, T_ee / q_follower and felt_nm)."""

    t: float
    q_leader: np.ndarray
    qd_leader: np.ndarray
    trigger: float
    q_follower: np.ndarray
    felt_nm: float
    T_ee: np.ndarray
    obs: dict = field(default_factory=dict)
    seen: dict = field(default_factory=dict)
    # the follower's external-torque estimate per joint [N*m] (NEXT / DOB: what the leader's feedback is made
    # from, before its contact gate and gain), for scripts that feel one joint (cap-screw: the wrist roll)
    tau_ext: np.ndarray = field(default_factory=lambda: np.zeros(0))


def percept(r, data, ee_site: int, obs: dict) -> Percept:
    """What the operator has at a tick (r: the pair's TickRecord): the gripper pose seen (the twin's `ee`
    site), the feedback felt on the leader, the task's objects as seen (obs)."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = data.site_xmat[ee_site].reshape(3, 3), data.site_xpos[ee_site]
    fb = r.tau_feedback
    felt = float(np.sum(np.abs(fb))) if fb is not None and np.all(np.isfinite(fb)) else 0.0
    return Percept(t=r.t, q_leader=r.leader.q, qd_leader=r.leader.q_dot, trigger=r.leader.gripper_pos,
                   q_follower=r.follower.q, felt_nm=felt, T_ee=T, obs=obs,
                   tau_ext=np.asarray(r.tau_ext, dtype=float))


class Operator:
    """Holds the reference (q_des, grip) and turns it into hand torques; scripts drive it via moves.

    fk/jac: follower description (hardware.arms.dynamics.ArmDynamics.fk/.jacobian); q_min/q_max: follower
    limits [rad]; to_leader: follower joints -> leader joints (the pair's JointMap.backward); dt: period."""

    def __init__(self, fk, jac, q_min, q_max, to_leader, dt: float, q_start):
        self.fk, self.jac, self.q_min, self.q_max = fk, jac, np.asarray(q_min), np.asarray(q_max)
        self.to_leader, self.dt = to_leader, float(dt)
        self.q_des = np.asarray(q_start, float).copy()
        self.b = np.zeros_like(self.q_des)
        self.servo_on = True
        self.grip = 0.0  # trigger fraction asked for
        self.q_ref_l = self.to_leader(self.q_des)
        self.qd_ref_l = np.zeros_like(self.q_ref_l)
        self.p: Percept | None = None
        self.log: dict = {}  # the running script's record (retries, contacts felt)
        self.nudge = np.zeros(2)  # m, world xy: the visual correction of a held tool (scripts.aim_tool)

    # -- per tick --------------------------------------------------------------------------------------
    def decide(self, p: Percept, dt_decide: float) -> None:
        """Update the lean and the leader reference from a percept (after the script set q_des)."""
        self.p = p
        if self.servo_on:
            self.b = servo_update(self.b, self.q_des, p.q_follower, dt_decide)
        ref = self.to_leader(np.clip(self.q_des + self.b, self.q_min, self.q_max))
        self.qd_ref_l = (ref - self.q_ref_l) / dt_decide
        self.q_ref_l = ref

    def torques(self, q_l, qd_l, trigger) -> np.ndarray:
        """Hand torques on the leader's joints + trigger [N*m] (n + 1)."""
        tau = hand_torque(q_l, qd_l, self.q_ref_l, self.qd_ref_l)
        return np.append(tau, trigger_torque(trigger, self.grip))

    # -- targets ------------------------------------------------------------------------------------------
    def aim(self, T_ee_des: np.ndarray, iters: int = 4) -> float:
        """Set q_des by IK toward a gripper pose (warm start: the current q_des); returns the position
        residual [m]."""
        q, res = aim_joints(self.fk, self.jac, self.q_des, T_ee_des, self.q_min, self.q_max, iters)
        self.q_des = self.q_des + np.clip(q - self.q_des, -AIM_STEP_RAD, AIM_STEP_RAD)
        return res

    def ee_pose_des(self) -> np.ndarray:
        return self.fk(self.q_des)
