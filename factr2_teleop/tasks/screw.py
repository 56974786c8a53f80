"""Cap-screwing demonstrations (cap-screw; SIMULATED): reach the lid by sight, grasp it, turn it on in wrist
strokes with regrasps, and stop on the torque felt at the wrist.

What the script uses, and nothing else: the lid's and the jar's poses as the simulated camera reports them
(op.p.seen: bias, noise, latency, frozen while the hand hides them), the follower's own pose and joints, and
the external-torque estimate (op.p.tau_ext: the wrist roll's to stop, the shoulder's and elbow's to feel a
touch; NEXT or the disturbance observer, what the leader's feedback is made from). Never the twin's truth,
never the episode's params (thread friction, gasket, strip torque and where the thread catches are hidden).

How a person does it: look at the lid for a moment, come down over it with the fingers open, close them
(centring by feel: where the first finger to touch pushes the hand tells where the lid really is; once
across the fingers, once along them), twist the wrist clockwise as far as it goes, open, twist back, grasp
again. The torque felt while the lid runs down the thread is its running friction (unknown, learnt each
stroke by feel); once the lid seats the torque climbs, and the operator stops when it has climbed
TARGET_RISE_NM above the running torque, holds a moment, lets go.
"""

from __future__ import annotations

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.operator import min_jerk
from factr2_teleop.tasks.scripts import DECIDE_DT_S, go_joints, grip, joint_move_s, move, wait
from hardware.sim.tasks import cap_screw as C

WRIST = 5  # the wrist roll, the last joint (q6 up: the gripper turns counter-clockwise from above)
STROKE_FROM_RAD, STROKE_TO_RAD = 1.85, -1.85  # rad of q6: one clockwise twist (212 deg) of the wrist
TURN_RAD_S = 0.5  # rad/s: one steady pace per stroke (the wrist estimate's bias moves with the pace)
TARGET_RISE_NM = 0.10  # N*m above the running torque felt: where the operator stops
SLOW_RISE_NM = 0.03  # N*m above the running torque: no longer running torque (the lid has met the jar)
EMA_S = 0.05  # s: how the operator's sense of torque smooths the estimate
BASE_MIN = 10  # decisions of running torque that make a stroke's own baseline
RUNNING_SKIP_RAD = 0.4  # rad into a stroke before its torque counts toward the running torque
GRASP_ABOVE_JAR_M = 0.007  # m: fingertips this far above the jar's top (as seen) when grasping
GRASP_BELOW_TOP_M = 0.011  # m: fingertips this far below the lid's top (as felt) when grasping: the lid is
# 16 mm tall and sinks up to 4 mm as it is screwed on
TOUCH_FROM_M, TOUCH_TO_M, TOUCH_M_S = 0.015, 0.012, 0.012  # m above / below the seen top, m/s: the touch
GUARD_NM = 2.0  # N*m: a jump of the shoulder + elbow estimates while lowering that means a touch
LIFT_ON_TOUCH_M = 0.003  # m: back up after such a touch
TIP_M = 0.01  # m: fingertips beyond the ee site
MAX_STROKES = 7
PROBE_SETTLE_S = 0.5  # s: holding still over the lid before a probe closes the fingers
CONFIRM = 2  # decisions in a row above the target before the operator believes it is tight
LOOK_S = 0.4  # s: looking at the lid and the jar before reaching


def _seen_pos(op, name):
    s = op.p.seen.get(name)
    if s is None or not np.all(np.isfinite(s.pos_m)):
        return None
    return np.asarray(s.pos_m, float)


def look(op, seconds: float = LOOK_S):
    """Average what the camera reports of the lid and the jar over `seconds` (visible frames only); returns
    (lid rim centre [m], jar base centre [m]) as believed."""
    cap, jar = [], []
    for _ in range(max(1, round(seconds / DECIDE_DT_S))):
        yield
        for name, acc in (("cap", cap), ("jar", jar)):
            s = op.p.seen.get(name)
            if s is not None and s.visible and np.all(np.isfinite(s.pos_m)):
                acc.append(np.asarray(s.pos_m, float))
    while not jar:  # never seen yet: keep looking (the camera's first frame arrives after its latency)
        yield
        p = _seen_pos(op, "jar")
        if p is not None:
            jar.append(p)
    jar_p = np.mean(jar, axis=0)
    cap_p = np.mean(cap, axis=0) if cap else jar_p + [0, 0, C.JAR_H_M]
    return cap_p, jar_p


def _wrist_pose(op, T_goal, q6: float) -> np.ndarray:
    """Joints for a top-down gripper at T_goal's position with the wrist roll at q6: the roll turns the
    gripper about its own approach axis, on which the ee site lies, so any q6 keeps the position (a round lid
    suits any yaw)."""
    q, _ = K.solve_ik(op.fk, op.jac, op.q_des, T_goal, op.q_min, op.q_max, iters=60)
    q[WRIST] = q6
    return q


def _descend(op, q_to, seconds: float):
    """Lower the hand to q_to (joint space, min-jerk); stops where a touch is felt (the arm's shoulder and
    elbow estimates jump by GUARD_NM: a fingertip on the jar, the camera's height was off) and comes back up
    LIFT_ON_TOUCH_M. Returns the height change [m] the operator now adds to its grasp height (0: none)."""
    def load():
        return float(np.sum(np.abs(op.p.tau_ext[1:3]))) if op.p.tau_ext.size >= 3 else 0.0

    q0, base = op.q_des.copy(), load()
    n = max(1, round(joint_move_s(op, q_to, seconds) / DECIDE_DT_S))
    for k in range(1, n + 1):
        op.q_des = q0 + min_jerk(k / n) * (np.asarray(q_to) - q0)
        yield
        if np.isfinite(base) and load() - base > GUARD_NM:
            T = op.fk(op.q_des)
            up = T[2, 3] - op.fk(np.asarray(q_to))[2, 3] + LIFT_ON_TOUCH_M
            op.q_des = _wrist_pose(op, K.pose(T[:3, :3], T[:3, 3] + [0, 0, LIFT_ON_TOUCH_M]), q_to[WRIST])
            yield from wait(op, 0.3)
            return up
    return 0.0


def _find_top(op, axis, top_seen: float):
    """Close the fingers over the lid and lower them onto its top until the touch is felt: the lid's height
    by feel (the camera's is off by its bias, up to ~7 mm, enough to close the fingers on the jar below).
    Returns the lid top's height [m] (the seen one if nothing was felt)."""
    q6 = float(op.q_des[WRIST])
    R = op.fk(op.q_des)[:3, :3]
    yield from grip(op, 1.0, 0.3)
    yield from go_joints(op, _wrist_pose(op, K.pose(R, [*axis, top_seen + TIP_M + TOUCH_FROM_M]), q6), 0.6)
    yield from wait(op, 0.3)
    q_to = _wrist_pose(op, K.pose(R, [*axis, top_seen + TIP_M - TOUCH_TO_M]), q6)
    up = yield from _descend(op, q_to, (TOUCH_FROM_M + TOUCH_TO_M) / TOUCH_M_S)
    top = (float(op.fk(q_to)[2, 3]) + up - LIFT_ON_TOUCH_M - TIP_M) if up > 0 else top_seen
    yield from grip(op, 0.0, 0.3)
    yield from go_joints(op, _wrist_pose(op, K.pose(R, [*axis, top + TIP_M + 0.01]), q6), 0.4)
    return top


def _probe(op, axis, z_grasp: float, q6: float):
    """Feel where the lid is across the fingers: close on it where it is believed to be and let the hand be
    pushed (the first finger to touch pushes the arm until the other one touches too); returns the believed
    axis moved by that push (world x, y) [m]. One probe finds the offset along the fingers' closing line."""
    T = K.pose(op.fk(op.q_des)[:3, :3], [*axis, z_grasp])
    z_grasp += yield from _descend(op, _wrist_pose(op, T, q6), 0.8)
    yield from wait(op, PROBE_SETTLE_S)  # the lean brings the follower onto the reference
    before = op.p.T_ee[:3, 3].copy()
    op.servo_on = False  # let the hand be pushed
    yield from grip(op, 1.0, 0.4)
    yield from wait(op, 0.4)
    push = op.p.T_ee[:3, 3] - before
    yield from grip(op, 0.0, 0.3)
    yield from wait(op, 0.2)
    op.servo_on = True
    return np.asarray(axis, float) + push[:2], z_grasp


def cap_screw(op, params, rng: np.random.Generator):
    """The demonstration; `params` is not read (the operator knows only what it sees and feels)."""
    del params
    speed = rng.uniform(0.85, 1.2)
    turn_w = TURN_RAD_S * rng.uniform(0.85, 1.15)
    rise_target = TARGET_RISE_NM * rng.uniform(0.95, 1.05)  # a person's own sense of "tight"
    out = op.log = {"gave_up": False, "retries": 0, "felt": [], "strokes": 0}
    yield
    cap_p, jar_p = yield from look(op)
    axis = np.array([cap_p[0], cap_p[1]])  # believed axis of the lid (x, y) [m]
    z_grasp = jar_p[2] + C.JAR_H_M + GRASP_ABOVE_JAR_M + TIP_M  # ee site height when grasping [m]
    T_over = K.pose(K.down_rotation(0.0), [*axis, z_grasp + 0.06])
    q_over = _wrist_pose(op, T_over, STROKE_FROM_RAD)
    yield from go_joints(op, q_over, 2.0 * speed)
    top = yield from _find_top(op, axis, cap_p[2] + C.CAP_H_M)
    out["top_felt_mm"] = round((top - cap_p[2] - C.CAP_H_M) * 1e3, 1)  # felt minus seen
    # fingertips GRASP_BELOW_TOP_M under the lid's top as felt, and never below the jar's top as seen + 2 mm
    z_grasp = max(top - GRASP_BELOW_TOP_M, jar_p[2] + C.JAR_H_M + 0.002) + TIP_M
    yield from wait(op, 0.3)
    for q6 in (STROKE_FROM_RAD, STROKE_FROM_RAD - np.pi / 2):  # across the fingers, then along them
        axis, z_grasp = yield from _probe(op, axis, z_grasp, q6)
    out["centred_mm"] = np.round((axis - cap_p[:2]) * 1e3, 1).tolist()
    running: list[float] = []  # the last stroke's running torque felt [N*m]
    felt = 0.0
    tight = False
    for stroke in range(MAX_STROKES):
        out["strokes"] = stroke + 1
        # down to the lid with the wrist at the stroke's start, fingers open
        T_down = K.pose(op.fk(op.q_des)[:3, :3], [*axis, z_grasp])
        q_down = _wrist_pose(op, T_down, STROKE_FROM_RAD)
        z_grasp += yield from _descend(op, q_down, 0.8 * speed)
        yield from wait(op, 0.2)
        yield from grip(op, 1.0, 0.4 * speed)
        yield from wait(op, 0.4)
        op.servo_on = False  # the hand holds the leader softly while it turns: no leaning on the joint error
        q_turn = op.q_des.copy()
        ema, above = None, 0
        q6 = q_turn[WRIST]
        this: list[float] = []  # this stroke's running torque (the wrist's estimate bias moves with its pose)
        while q6 > STROKE_TO_RAD:
            tau = -float(op.p.tau_ext[WRIST]) if op.p.tau_ext.size > WRIST else 0.0  # resisting: tau_ext < 0
            ema = tau if ema is None else ema + (DECIDE_DT_S / EMA_S) * (tau - ema)
            turned = q_turn[WRIST] - q6
            base = float(np.median(this)) if len(this) >= BASE_MIN else (
                float(np.median(running)) if running else None)
            rise = ema - base if base is not None else 0.0
            if turned > RUNNING_SKIP_RAD and rise < SLOW_RISE_NM:
                this.append(ema)
            above = above + 1 if base is not None and rise >= rise_target else 0
            if above >= CONFIRM:
                felt = ema
                tight = True
                out["felt"].append({"t": round(op.p.t, 2), "by": "wrist torque", "rise_nm": round(rise, 3),
                                    "running_nm": round(base, 3)})
                break
            q6 -= turn_w * DECIDE_DT_S
            op.q_des = q_turn.copy()
            op.q_des[WRIST] = q6
            yield
        running = this if len(this) >= BASE_MIN else running
        yield from wait(op, 0.3)  # holds the torque a moment
        yield from grip(op, 0.0, 0.4 * speed)
        yield from wait(op, 0.4)
        op.servo_on = True
        if tight:
            break
        q_back = op.q_des.copy()
        q_back[WRIST] = STROKE_FROM_RAD
        yield from go_joints(op, q_back, 1.2 * speed)
    else:
        out["gave_up"] = True
    out["felt_nm"] = round(felt, 3)
    T = op.fk(op.q_des)
    yield from move(op, K.pose(T[:3, :3], T[:3, 3] + [0, 0, 0.06]), 0.9 * speed)
    return out
