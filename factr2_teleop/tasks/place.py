"""Pick-and-insert demonstrations (peg-insert, press-fit): pick the object from the table, carry it over the
target, line it up by eye, push it home while feeling for contact; a contact felt before the object has
engaged (or an object that stops going down) means a misjudged approach: back off, look again, retry.

One script for both tasks, parameterised by a Place (what to grasp, where the target is, how deep "home" is).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.operator import interp_pose
from factr2_teleop.tasks.scripts import (
    DECIDE_DT_S,
    FELT_NM,
    aim_tool,
    best_down_yaw,
    grip,
    move,
    wait,
    yaw_of,
)
from hardware.sim.tasks import peg_insert as PEG
from hardware.sim.tasks import press_fit as PF

P_MISALIGN = 0.35  # share of approaches that arrive misaligned (a person misjudges the target)
MAX_TRIES = 4  # attempts before giving up
ALIGNED_M = 0.0008  # m: "looks aligned" -- the operator pushes only then (or after ALIGN_PATIENCE_S)
ALIGN_PATIENCE_S = 2.5
HOLD_DRIFT_M = 0.0015  # m: while the object is out of its seat and further off line than this, the push
# pauses (the hole's 2 mm chamfer, the studs' rounded tops guide an object that is closer)
DESCENT_SLACK_S = 3.0  # s: extra time a descent may take for its pauses
STALL_S = 0.6  # s: an object that has not gone down 0.5 mm in this long while pushed is stuck
GRASP_TRIES = 3
ARRIVE_M = 0.002  # m: the gripper is "there" when seen this close to where it was sent
ARRIVE_PATIENCE_S = 2.0
DEEP_M = 0.01  # m: an object this far past where it engages that stops is left there (it slid in the hand)


@dataclass(frozen=True)
class Place:
    """obj: observe() prefix of the held object ("peg" -> peg_pos/peg_rot); target: params prefix of where it
    goes ("hole" -> hole_pos/hole_yaw); half_h [m]: object centre to its lower end; grasp_below_m: ee site
    this far below the object's top; above_m: lower end this far above the engaging height when lining up;
    engage_z_m: lower-end height [m] where the object starts to engage; home_z_m: lower-end height when done
    (plus done_tol_m); push_m: how far past home the hand aims."""

    obj: str
    target: str
    half_h: float
    grasp_below_m: float
    engage_z_m: float
    home_z_m: float
    done_tol_m: float
    above_m: float = 0.012
    push_m: float = 0.002
    touch_is_jam: bool = True  # a touch felt before engaging means a miss (peg on the rim); False: the
    # first touch is expected (a block on its studs) and the operator presses on until it stops going down
    press_on_top: bool = False  # once engaged, let go and press the object home on its top (a brick held
    # at its sides slips in the fingers before its studs give)

PEG_PLACE = Place("peg", "hole", PEG.PEG_HALF[2], 0.018, engage_z_m=PEG.DEPTH_M,
                  home_z_m=PEG.DEPTH_M - PEG.INSERT_DEPTH_M, done_tol_m=-0.0005)
_BLOCK_H = 0.5 * (PF.SKIRT_H_M + PF.CAP_H_M)
PRESS_PLACE = Place("block", "base", _BLOCK_H, 0.006, engage_z_m=PF.PLATE_TOP_M + 2 * PF.STUD_HALF[2],
                    home_z_m=PF.PLATE_TOP_M, done_tol_m=PF.SEAT_TOL_M * 0.4, push_m=0.004,
                    touch_is_jam=False, press_on_top=True)
PRESS_DEPTH_M = 0.012  # m: how far below the block's top the pressing fingertips aim
PRESS_S = 3.5  # s: the longest press


def _upright(yaw: float, p) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return K.pose(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), p)


def pick_and_place(op, params: dict, rng: np.random.Generator, pl: Place, held: bool = False):
    """held: the object is already in the hand (an operator taking over from a policy that carries it):
    no grasp, and the approach is looked at carefully (no misjudged arrival), from where the arm is."""
    speed = rng.uniform(0.8, 1.3)  # this demonstration's pace (1 = nominal)

    def dur(s):
        return s * speed * rng.uniform(0.85, 1.15)

    out = op.log = {"gave_up": False, "retries": 0, "felt": []}  # op.log: read on a timeout too
    yield
    if not held:
        for _grasp in range(GRASP_TRIES):
            obs = op.p.obs
            top = obs[f"{pl.obj}_pos"] + [0, 0, pl.half_h]
            grasp_p = top - [0, 0, pl.grasp_below_m]
            yaw = best_down_yaw(op, grasp_p, yaw_of(obs[f"{pl.obj}_rot"]), np.pi / 2)
            bump = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.0, 0.05)])
            yield from move(op, K.pose(K.down_rotation(yaw), grasp_p + [0, 0, 0.07]), dur(1.8), bump=bump)
            T_grasp = K.pose(K.down_rotation(yaw), grasp_p)
            yield from move(op, T_grasp, dur(1.0))
            yield from _arrive(op, T_grasp)  # closes only with the fingers seen around the object
            yield from grip(op, 1.0, dur(0.5))
            yield from wait(op, 0.5)
            yield from move(op, K.pose(K.down_rotation(yaw), grasp_p + [0, 0, 0.075]), dur(0.9))
            if np.all(op.p.obs["finger_touch"]) and op.p.obs[f"{pl.obj}_pos"][2] > top[2] - pl.half_h + 0.03:
                break
            out["regrasps"] = out.get("regrasps", 0) + 1  # not in the hand: open, look again, grasp again
            yield from grip(op, 0.0, dur(0.4))
            yield from wait(op, 0.5)
        else:
            out["gave_up"] = True
            return out

    def in_hand() -> np.ndarray:  # where the object sits in the gripper, as seen now
        o = op.p.obs
        return np.linalg.inv(op.p.T_ee) @ K.pose(o[f"{pl.obj}_rot"], o[f"{pl.obj}_pos"])

    grasped = {"T": in_hand()}
    op.nudge = np.zeros(2)

    def tool():  # as last looked at (a swinging object must not feed back into the target)
        return grasped["T"]

    def seen():  # the object's lower end: what has to meet the target
        o = op.p.obs
        R = o[f"{pl.obj}_rot"]
        return o[f"{pl.obj}_pos"] - pl.half_h * (R[:, 2] if R[2, 2] >= 0 else -R[:, 2])

    goal, goal_yaw = np.asarray(params[f"{pl.target}_pos"], float), float(params[f"{pl.target}_yaw"])
    obj_yaw = yaw_of(op.p.obs[f"{pl.obj}_rot"])
    target_yaw = goal_yaw + np.pi / 2 * np.round((obj_yaw - goal_yaw) / (np.pi / 2))
    off, dyaw = np.zeros(3), 0.0
    if not held and rng.random() < P_MISALIGN:  # misjudged: arrives beside the target or turned
        if rng.random() < 0.6:
            a = rng.uniform(0, 2 * np.pi)
            off = rng.uniform(0.0025, 0.004) * np.array([np.cos(a), np.sin(a), 0.0])
        else:
            dyaw = rng.choice([-1, 1]) * np.deg2rad(rng.uniform(3.0, 6.0))
    z_above = pl.engage_z_m + pl.half_h + pl.above_m  # object centre when lining up
    bump = np.array([rng.uniform(-0.02, 0.02), 0.0, rng.uniform(0.0, 0.04)])
    yield from move(op, _upright(target_yaw + dyaw, goal + off + [0, 0, z_above]), dur(2.0), tool=tool,
                    bump=bump)
    for _attempt in range(MAX_TRIES):
        T_goal = _upright(target_yaw + dyaw, goal + off + [0, 0, z_above])
        grasped["T"] = in_hand()  # looks at how the object sits now (a jam may have tilted it)
        yield from move(op, T_goal, dur(0.8), tool=tool, seen=seen)  # over the (believed) target
        yield from _line_up(op, T_goal, tool, seen)
        out["touched"] = False
        status = yield from _push_home(op, pl, T_goal, dur(2.4), out, tool, seen)
        if status == "home":
            break
        if status == "engaged":  # pressed on its top: it is no longer in the hand, whatever the result
            out["gave_up"] = not (yield from _press_on_top(op, pl, dur))
            break
        out["retries"] += 1
        yield from move(op, T_goal @ K.pose(np.eye(3), [0, 0, 0.006]), dur(0.6), tool=tool, seen=seen)
        off, dyaw = np.zeros(3), 0.0  # looks again, closer: this time the estimate is right
    else:
        out["gave_up"] = True
    yield from grip(op, 0.0, dur(0.4))
    yield from wait(op, 0.3)
    T = op.ee_pose_des()
    yield from move(op, K.pose(T[:3, :3], T[:3, 3] + [0, 0, 0.08]), dur(0.9))
    return out


def _press_on_top(op, pl: Place, dur):
    """Let go of an engaged object, close the fingers above it and press its top until it is home (True)."""
    yield from grip(op, 0.0, dur(0.4))
    T = op.ee_pose_des()
    yield from move(op, K.pose(T[:3, :3], T[:3, 3] + [0, 0, 0.04]), dur(0.6))
    o = op.p.obs
    R = o[f"{pl.obj}_rot"]
    top = o[f"{pl.obj}_pos"] + pl.half_h * (R[:, 2] if R[2, 2] >= 0 else -R[:, 2])
    tip = 0.01  # m: fingertips beyond the ee site
    for _ in range(round(1.5 / DECIDE_DT_S)):  # closes the fingers only once they are seen clear of it
        if not np.any(op.p.obs["finger_touch"]) and op.p.T_ee[2, 3] - tip > top[2] + 0.008:
            break
        yield
    yield from grip(op, 1.0, dur(0.4))
    yield from move(op, K.pose(T[:3, :3], top + [0, 0, tip + 0.01]), dur(0.6))
    n = round(PRESS_S / DECIDE_DT_S)
    reached = False
    for k in range(1, n + 1):
        a = min(1.0, 2.0 * k / n)  # down in the first half, then hold the push
        op.aim(K.pose(T[:3, :3], top + [0, 0, tip + 0.01 - a * (0.01 + PRESS_DEPTH_M)]))
        yield
        o = op.p.obs
        R = o[f"{pl.obj}_rot"]
        low = o[f"{pl.obj}_pos"] - pl.half_h * (R[:, 2] if R[2, 2] >= 0 else -R[:, 2])
        reached = bool(low[2] <= pl.home_z_m + pl.done_tol_m)
        if reached:
            yield from wait(op, 0.4)  # holds the push a moment: "click"
            break
    T = op.ee_pose_des()
    yield from move(op, K.pose(T[:3, :3], T[:3, 3] + [0, 0, 0.03]), dur(0.5))
    for _ in range(round(1.5 / DECIDE_DT_S)):  # the fingers leave it before they open (they would drag it)
        if not np.any(op.p.obs["finger_touch"]):
            break
        yield
    return reached


def _arrive(op, T):
    """Wait (the lean keeps working) until the gripper is seen within ARRIVE_M of T, or patience runs out."""
    for _ in range(round(ARRIVE_PATIENCE_S / DECIDE_DT_S)):
        if np.linalg.norm(op.p.T_ee[:3, 3] - T[:3, 3]) < ARRIVE_M:
            return
        yield


def _line_up(op, T_goal, tool, seen):
    """Hold over the target, nudging, until the object looks aligned for 0.2 s (or patience runs out)."""
    still = 0
    for _ in range(round(ALIGN_PATIENCE_S / DECIDE_DT_S)):
        aim_tool(op, T_goal, tool, seen)
        yield
        still = still + 1 if np.linalg.norm(T_goal[:2, 3] - seen()[:2]) < ALIGNED_M else 0
        if still * DECIDE_DT_S >= 0.2:
            return


def _push_home(op, pl: Place, T_goal, seconds: float, out: dict, tool, seen):
    """Lower the held object from T_goal to home; 'home', or 'jammed' when contact is felt before it has
    engaged, or it stops going down while pushed."""
    T_end = T_goal.copy()
    T_end[2, 3] = pl.home_z_m + pl.half_h - pl.push_m
    ds = 1.0 / max(1, round(seconds / DECIDE_DT_S))
    s = 0.0
    window = round(STALL_S / DECIDE_DT_S)
    heights: list[float] = []
    for _ in range(round((seconds + DESCENT_SLACK_S) / DECIDE_DT_S)):
        T = interp_pose(T_goal, T_end, s)
        aim_tool(op, T, tool, seen)
        yield
        low = seen()
        if low[2] <= pl.home_z_m + pl.done_tol_m:
            return "home"
        engaged = low[2] < pl.engage_z_m - 0.003
        drift = float(np.linalg.norm(T[:2, 3] - low[:2]))
        if engaged or drift < HOLD_DRIFT_M:  # a person pauses the push while the object drifts off line
            s = min(1.0, s + ds)
        heights.append(float(low[2]))
        stalled = (len(heights) > window and heights[-window] - low[2] < 0.0005
                   and T[2, 3] - pl.half_h < low[2] - 0.004)
        felt = op.p.felt_nm > FELT_NM and not engaged
        if felt and not out.get("touched"):
            out["touched"] = True
            out["felt"].append({"t": round(op.p.t, 2), "by": "feedback", "off_mm": round(drift * 1e3, 2),
                                "height_mm": round(float(low[2]) * 1e3, 1)})
        # a block engaged on its studs that stops is pressed harder (the hand keeps aiming past home), not
        # pulled back; anything else that stops, or a peg that touches before entering, is a miss
        if pl.press_on_top and engaged and stalled:
            return "engaged"
        if stalled and low[2] <= pl.engage_z_m - DEEP_M:  # deep in and it stopped: left there (it slid up
            return "home"  # in the fingers); the detectors decide whether that is deep enough
        if (felt and pl.touch_is_jam) or (stalled and (pl.touch_is_jam or not engaged)):
            out["jams"] = out.get("jams", 0) + 1
            return "jammed"
    return "home" if seen()[2] <= pl.home_z_m else "jammed"  # out of time: in deep enough, or not


def peg_insert(op, params, rng, held: bool = False):
    return (yield from pick_and_place(op, params, rng, PEG_PLACE, held))


def press_fit(op, params, rng, held: bool = False):
    return (yield from pick_and_place(op, params, rng, PRESS_PLACE, held))


RESUMES_HELD = ("peg-insert", "press-fit")  # scripts that can start from an object already in the hand
