"""Scripted demonstrations, one generator per task, driving an Operator (operator.py) one decision per yield.

A script reads op.p (the Percept: follower pose and task objects as seen, the feedback felt) and sets the
operator's targets. It behaves like a person: per-episode speed and per-move jitter, a curved path, an
approach that sometimes arrives misaligned (noise on where it thinks the target is), contact felt through the
leader's force feedback, then backing off and realigning. Its result (returned by the generator) is a dict:
{"gave_up": bool, "retries": int, "felt": [t, ...]}; success is decided by the task's detectors, not here.
"""

from __future__ import annotations

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.operator import DECIDE_EVERY, interp_pose
from hardware.sim.tasks import peg_insert as PEG

DECIDE_DT_S = DECIDE_EVERY / 500.0  # s: one decision (the loop runs at 500 Hz)
FELT_NM = 0.15  # N*m: ||feedback torque||_1 on the leader a person notices as "it hit something"
P_MISALIGN = 0.35  # share of approaches that arrive misaligned (a person misjudges the hole)
MAX_TRIES = 4  # insert attempts before giving up
SEE_KI = 0.8  # 1/s: how fast the operator nudges a held tool onto where they want it (visual correction)
SEE_MAX_M = 0.01  # m: the largest such nudge
SEE_DEADBAND_M = 0.00015  # m: an error this small is left alone
ALIGNED_M = 0.0008  # m: "looks aligned" -- the operator pushes only then (or after ALIGN_PATIENCE_S)
ALIGN_PATIENCE_S = 2.5
HOLD_DRIFT_M = 0.0015  # m: while the peg is out of the hole and further off line than this, the push pauses
# (the hole's 2 mm chamfer guides a peg that is closer)
DESCENT_SLACK_S = 3.0  # s: extra time a descent may take for its pauses
STALL_S = 0.6  # s: a held peg that has not gone down 0.5 mm in this long is stuck


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


def _upright(yaw: float, p) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return K.pose(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), p)


def peg_insert(op, params: dict, rng: np.random.Generator):
    speed = rng.uniform(0.8, 1.3)  # this demonstration's pace (1 = nominal)

    def dur(s):
        return s * speed * rng.uniform(0.85, 1.15)

    out = op.log = {"gave_up": False, "retries": 0, "felt": []}  # op.log: read on a timeout too
    yield
    obs = op.p.obs
    peg_top = obs["peg_pos"] + [0, 0, PEG.PEG_HALF[2]]
    grasp_p = peg_top - [0, 0, 0.018]  # the ee site 18 mm below the top: fingers over the upper 28 mm
    yaw = best_down_yaw(op, grasp_p, yaw_of(obs["peg_rot"]), np.pi / 2)
    above = K.pose(K.down_rotation(yaw), grasp_p + [0, 0, 0.07])
    bump = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.0, 0.05)])
    yield from move(op, above, dur(1.8), bump=bump)
    yield from move(op, K.pose(K.down_rotation(yaw), grasp_p), dur(1.0))
    yield from wait(op, 0.3)
    yield from grip(op, 1.0, dur(0.5))
    yield from wait(op, 0.5)
    yield from move(op, K.pose(K.down_rotation(yaw), grasp_p + [0, 0, 0.075]), dur(0.9))

    grasped = {"T": _peg_in_hand(op)}
    op.nudge = np.zeros(2)

    def seen():  # the peg's lower end: what has to meet the hole
        o = op.p.obs
        z = o["peg_rot"][:, 2] if o["peg_rot"][2, 2] >= 0 else -o["peg_rot"][:, 2]
        return o["peg_pos"] - PEG.PEG_HALF[2] * z

    def tool():  # where the peg sits in the gripper, as last looked at
        return grasped["T"]

    hole, hole_yaw = np.asarray(params["hole_pos"], float), float(params["hole_yaw"])
    peg_yaw = yaw_of(op.p.obs["peg_rot"])
    target_yaw = hole_yaw + np.pi / 2 * np.round((peg_yaw - hole_yaw) / (np.pi / 2))
    off, dyaw = np.zeros(3), 0.0
    if rng.random() < P_MISALIGN:  # misjudged: arrives beside the hole or turned
        if rng.random() < 0.6:
            a = rng.uniform(0, 2 * np.pi)
            off = rng.uniform(0.0015, 0.003) * np.array([np.cos(a), np.sin(a), 0.0])
        else:
            dyaw = rng.choice([-1, 1]) * np.deg2rad(rng.uniform(3.0, 6.0))
    z_above = PEG.DEPTH_M + PEG.PEG_HALF[2] + 0.012  # peg centre with its bottom 12 mm above the fixture
    bump = np.array([rng.uniform(-0.02, 0.02), 0.0, rng.uniform(0.0, 0.04)])
    yield from move(op, _upright(target_yaw + dyaw, hole + off + [0, 0, z_above]), dur(2.0), tool=tool,
                    bump=bump)
    for _attempt in range(MAX_TRIES):
        T_goal = _upright(target_yaw + dyaw, hole + off + [0, 0, z_above])
        grasped["T"] = _peg_in_hand(op)  # looks at how the peg sits now (a jam may have tilted it)
        yield from move(op, T_goal, dur(0.8), tool=tool, seen=seen)  # over the (believed) hole
        yield from _line_up(op, T_goal, tool, seen)
        status = yield from _descend(op, T_goal, dur(2.4), out, tool, seen)
        if status == "inserted":
            break
        out["retries"] += 1
        back = T_goal @ K.pose(np.eye(3), [0, 0, 0.006])  # back off: up 6 mm
        yield from move(op, back, dur(0.6), tool=tool, seen=seen)
        off, dyaw = np.zeros(3), 0.0  # looks again, closer: this time the estimate is right
    else:
        out["gave_up"] = True
    yield from grip(op, 0.0, dur(0.4))
    yield from wait(op, 0.3)
    T = op.ee_pose_des()
    yield from move(op, K.pose(T[:3, :3], T[:3, 3] + [0, 0, 0.08]), dur(0.9))
    return out


def _peg_in_hand(op) -> np.ndarray:
    o = op.p.obs
    return np.linalg.inv(op.p.T_ee) @ K.pose(o["peg_rot"], o["peg_pos"])


def _line_up(op, T_goal, tool, seen):
    """Hold over the target, nudging, until the peg looks aligned for 0.2 s (or patience runs out)."""
    still = 0
    for _ in range(round(ALIGN_PATIENCE_S / DECIDE_DT_S)):
        aim_tool(op, T_goal, tool, seen)
        yield
        still = still + 1 if np.linalg.norm(T_goal[:2, 3] - seen()[:2]) < ALIGNED_M else 0
        if still * DECIDE_DT_S >= 0.2:
            return


def _descend(op, T_goal, seconds: float, out: dict, tool, seen):
    """Lower the held peg from T_goal into the hole; 'inserted', or 'jammed' when contact is felt before the
    peg enters (or it stops going down)."""
    z_end = PEG.PEG_HALF[2] - 0.002  # peg centre with its bottom 2 mm below the table: keep pushing a little

    T_end = T_goal.copy()
    T_end[2, 3] = z_end
    ds = 1.0 / max(1, round(seconds / DECIDE_DT_S))
    s = 0.0
    window = round(STALL_S / DECIDE_DT_S)
    heights: list[float] = []
    for _ in range(round((seconds + DESCENT_SLACK_S) / DECIDE_DT_S)):
        T = interp_pose(T_goal, T_end, s)
        aim_tool(op, T, tool, seen)
        yield
        m = PEG.peg_metrics(op.p.obs["peg_pos"], op.p.obs["peg_rot"], op.p.obs["hole_pos"],
                            float(op.p.obs["hole_yaw"]))
        if m["bottom_z_m"] <= PEG.DEPTH_M - PEG.INSERT_DEPTH_M - 0.001:
            return "inserted"
        entered = m["bottom_z_m"] < PEG.DEPTH_M - 0.003
        drift = np.linalg.norm(T[:2, 3] - seen()[:2])
        if entered or drift < HOLD_DRIFT_M:  # a person pauses the push while the peg drifts off line
            s = min(1.0, s + ds)
        heights.append(m["bottom_z_m"])
        # it does not go down although the hand wants it well below: seen, not only felt
        stalled = (len(heights) > window and heights[-window] - m["bottom_z_m"] < 0.0005
                   and T[2, 3] - PEG.PEG_HALF[2] < m["bottom_z_m"] - 0.004)
        if not entered and (op.p.felt_nm > FELT_NM or stalled):
            out["felt"].append((round(op.p.t, 2), "feedback" if op.p.felt_nm > FELT_NM else "seen",
                                np.round(m["lateral_m"] * 1e3, 2).tolist(),
                                round(np.degrees(m["yaw_err_rad"]), 1),
                                round(np.degrees(m["tilt_rad"]), 1)))
            return "jammed"
    return "jammed"
    return "jammed"


SCRIPTS = {"peg-insert": peg_insert}
