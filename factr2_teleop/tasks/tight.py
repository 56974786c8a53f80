"""Tight-insert demonstrations (SIMULATED): reach by sight, find the bore by feel, stop on force.

The operator sees the pin and the fixture ONLY through the simulated pose detector (op.p.seen: name ->
hardware.sim.perception.Seen: calibration bias, noise, latency, occlusion near the gripper), knows
where its own arm is (the follower's reported joints through FK), and feels the
leader's force feedback (op.p.felt_nm). It never reads the twin's truth (op.p.obs): the bore's 0.2 mm per side
clearance is far below the detector's millimetres, so what sight gives is only where to start looking.

0. Brings the arm over the pin in joint space (from the session's stretched start pose the Cartesian aim
   stalls on the joint limits).
1. Look (Sight averages the detections frame by frame: the noise averages out, the bias does not), grasp the
   pin's head from above, low enough that the fingers cover the head whatever the seen height's bias; the
   grasp is checked by sight: once the hand has lifted, a pin still seen standing where it stood was not
   taken (a held one is hidden by the hand).
2. Carry it over the bore as seen, feel the carried weight held still (the baseline a touch is felt
   against), lower slowly until the touch is felt (or until it is felt far below the fixture's seen top:
   the pin went straight in).
3. Search by pecks (tight_pecks.py): lift the tip clear, move over the next point of a hexagonal grid
   around the touch (nearest first), press a few mm below the touch height with the hand's compliance (the
   lean on the joint error off) and rest; a hand that rests DROP_M lower than it rested on the fixture top
   has dropped into the bore (the chamfer leads a tip in from CAPTURE_M off the axis). A grid without a
   drop: lift, look again, search again.
4. Push it home on a felt push (over the baseline, like wipe.py's strokes); seated when the hand has stopped
   sinking for STILL_S deep in the bore (stop on force); a stop short of that depth is a jam: lift a little
   and push again.
5. Let go, lift.
"""

from __future__ import annotations

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.scripts import DECIDE_DT_S, best_down_yaw, go_joints, grip, move, wait, yaw_of
from factr2_teleop.tasks.tight_pecks import down_pose, hand_pose, pecks
from hardware.sim.tasks import tight_insert as TI

LOOK_S = 0.5  # s: how long it looks before it moves (some 15 camera frames)
GRASP_BELOW_M = 0.016  # m: ee site this far below the head's top as seen: the fingertips (10 mm below the ee
# site) 2 mm below the head's underside, so the 60 mm pads cover the whole 24 mm head unless the pin's seen
# height is 2 mm low, and 20 mm of it with the height seen 4 mm high (the detector's height bias is mm)
PIN_LEN_M = TI.SHAFT_L_M + 2 * TI.HEAD_HALF[2]
TIP_BELOW_EE_M = PIN_LEN_M - GRASP_BELOW_M  # m: the tip under the ee site when held as grasped
GRASP_TRIES = 3
LIFT_M = 0.075
READY_ABOVE_M = 0.05  # m: the hand first goes this far above its grasp in joint space (a session starts with
# the arm stretched at q = 0, from where the Cartesian aim ran into the joint limits and missed the pin)
APPROACH_ABOVE_M = 0.012  # m: tip this far above the fixture's seen top before the touch-down
TOUCH_SPEED_M_S = 0.008
TOUCH_MAX_M = 0.045  # m: the longest touch-down (past the seen top: straight in)
STRAIGHT_IN_M = 0.010  # m: a touch felt this far below the seen top means the pin went in on its own
TOUCH_FELT_NM = 0.08  # N*m: felt this much MORE than while carrying the pin in the air, it has touched (the
# held pin's weight is itself felt, 0.15-0.2 N*m at the leader: a person feels a change, not a level)
BASE_S = 0.4  # s: how long the carried weight is felt, held still, before the touch-down
PUSH_FELT_NM = (0.11, 0.15)  # N*m over the carried weight: the push home (drawn per episode; ~3-6 N)
DEPTH_KI = 0.05  # m per (N*m * s): how fast the aimed depth follows the felt push error (wipe.py's)
DEPTH_RANGE_M = (-0.003, 0.03)  # m: aimed depth below the touch, bounds
HOME_M = TI.DEPTH_M - 0.004  # m: sunk this far below the touch: deep in the bore
STILL_S = 0.5  # s: no sinking (< STILL_M) for this long while pushed: it has stopped
STILL_M = 0.0003
PUSH_S = 6.0  # s: the longest push home
JAM_TRIES = 3
SEARCHES = 2  # grids before giving up


class Sight:
    """What the operator has seen: per object, the mean of its detections (one per camera frame, counted
    once), restartable (look again)."""

    def __init__(self):
        self.sum: dict = {}
        self.n: dict = {}
        self.last: dict = {}
        self.rot: dict = {}

    def add(self, seen: dict | None) -> None:
        for k, s in (seen or {}).items():
            if not s.visible or not np.all(np.isfinite(s.pos_m)):
                continue
            if k in self.last and np.array_equal(self.last[k], s.pos_m):
                continue  # the same frame, held
            self.last[k] = np.array(s.pos_m, float)
            self.sum[k] = self.sum.get(k, 0.0) + self.last[k]
            self.n[k] = self.n.get(k, 0) + 1
            self.rot[k] = np.array(s.rot, float)

    def forget(self, k: str) -> None:
        self.sum.pop(k, None)
        self.n.pop(k, None)

    def pos(self, k: str) -> np.ndarray | None:
        return self.sum[k] / self.n[k] if self.n.get(k) else None

    def frames(self, k: str) -> int:
        return self.n.get(k, 0)


def tight_insert(op, params, rng: np.random.Generator, held: bool = False):
    """The script (a generator: one decision per yield); params are not read (the truth is in there)."""
    sight = Sight()
    inner = _script(op, rng, sight)
    while True:
        sight.add(getattr(op.p, "seen", None))
        try:
            next(inner)
        except StopIteration as stop:
            return stop.value
        yield


def _script(op, rng, sight: Sight):
    speed = rng.uniform(0.8, 1.3)

    def dur(s):
        return s * speed * rng.uniform(0.85, 1.15)

    out = op.log = {"gave_up": False, "retries": 0, "felt": [], "grasps": 0, "pecks": 0, "jams": 0}
    yield
    yield from wait(op, LOOK_S)
    if sight.pos("pin") is None or sight.pos("hole") is None:
        yield from wait(op, 1.0)  # nothing seen yet (dropped frames): look a while longer
    if sight.pos("pin") is None or sight.pos("hole") is None:  # no detector behind op.p.seen: blind
        out["gave_up"], out["result"] = True, "nothing seen"
        return out
    yield from _ready(op, sight.pos("pin"), dur)
    for _grasp in range(GRASP_TRIES):
        out["grasps"] += 1
        ok, yaw = yield from _grasp_pin(op, sight, rng, dur)
        if ok:
            break
    else:
        out["gave_up"] = True
        return out
    result = yield from _find_and_insert(op, sight, rng, dur, yaw, out)
    out["result"] = result
    out["gave_up"] = result != "seated"
    op.servo_on = True
    yield from grip(op, 0.0, dur(0.4))
    yield from wait(op, 0.3)
    T = hand_pose(op)
    yield from move(op, down_pose(yaw, T[:3, 3] + [0, 0, 0.06]), dur(0.9), T_from=T)
    return out


def _ready(op, pin, dur):
    """Bring the arm over the pin in joint space, from an IK solved from the middle of the joint ranges (the
    elbow up): from the stretched start pose the Cartesian aim stalls on the joint limits."""
    T = down_pose(0.0, np.asarray(pin, float) + [0, 0, TIP_BELOW_EE_M + READY_ABOVE_M])
    q, e = K.solve_ik(op.fk, op.jac, (op.q_min + op.q_max) / 2, T, op.q_min, op.q_max, iters=80)
    if np.linalg.norm(e[:3]) < 0.005:
        yield from go_joints(op, q, dur(1.5))


def _grasp_pin(op, sight: Sight, rng, dur):
    """Grasp the pin's head where it is seen; (True, gripper yaw) once it is in the hand."""
    p = sight.pos("pin")
    R = sight.rot["pin"]
    top = p + PIN_LEN_M * R[:, 2]
    grasp_p = top - [0, 0, GRASP_BELOW_M]
    yaw = best_down_yaw(op, grasp_p, yaw_of(R), np.pi / 2)
    bump = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.0, 0.05)])
    yield from grip(op, 0.0, 0.2)
    yield from move(op, down_pose(yaw, grasp_p + [0, 0, 0.07]), dur(1.8), bump=bump)
    yield from move(op, down_pose(yaw, grasp_p), dur(1.0))
    yield from wait(op, 0.4)
    yield from grip(op, 1.0, dur(0.5))
    yield from wait(op, 0.5)
    sight.forget("pin")  # from here on, a detection of the pin is a new look
    yield from move(op, down_pose(yaw, grasp_p + [0, 0, LIFT_M]), dur(0.9))
    yield from wait(op, 0.4)  # a pin left standing comes back into view (latency, frames)
    left = sight.pos("pin")
    in_hand = not (left is not None and left[2] < 0.02)  # seen standing where it was: not in the hand
    if not in_hand:
        yield from grip(op, 0.0, dur(0.4))
        yield from wait(op, 0.6)
    return in_hand, yaw


def _find_and_insert(op, sight: Sight, rng, dur, yaw: float, out: dict):
    """Over the bore as seen, touch down, search by feel, push home; 'seated', 'lost' or 'jammed'."""
    felt_target = rng.uniform(*PUSH_FELT_NM)
    for search in range(SEARCHES):
        hole = sight.pos("hole")
        top_z = hole[2] + TI.DEPTH_M  # the fixture's top, as seen
        centre = hole[:2].copy()
        above = np.array([*centre, top_z + APPROACH_ABOVE_M + TIP_BELOW_EE_M])
        bump = np.array([rng.uniform(-0.02, 0.02), 0.0, rng.uniform(0.0, 0.04)]) if search == 0 else None
        op.servo_on = True
        yield from move(op, down_pose(yaw, above), dur(2.0), bump=bump)
        yield from wait(op, 0.3)
        base = yield from _felt_base(op)
        z_touch = yield from _touchdown_pose(op, yaw, above, base, out)
        if z_touch is None:
            return "lost"
        op.servo_on = False  # from here the push comes from the hand's compliance (wipe.py)
        if z_touch < above[2] - APPROACH_ABOVE_M - STRAIGHT_IN_M:
            status = "dropped"  # felt far below the top: it went in on the way down
            z_touch = above[2] - APPROACH_ABOVE_M  # the hand's height with the tip at the top, as seen
        else:
            t0 = op.p.t
            status = yield from pecks(op, yaw, hand_pose(op)[:2, 3].copy(), z_touch, out)
            out["search_s"] = round(out.get("search_s", 0.0) + op.p.t - t0, 2)
        if status == "dropped":
            for _jam in range(JAM_TRIES):
                t0 = op.p.t
                status = yield from _push_home(op, yaw, z_touch, base, felt_target)
                out["push_s"] = round(out.get("push_s", 0.0) + op.p.t - t0, 2)
                if status == "seated":
                    return status
                out["jams"] += 1
            return "jammed"
        out["retries"] += 1  # nothing found: lift, look again
        op.servo_on = True
        T = hand_pose(op)
        yield from move(op, down_pose(yaw, T[:3, 3] + [0, 0, 0.02]), dur(0.6), T_from=T)
        yield from wait(op, 0.5)
    return "lost"


def _felt_base(op):
    """The feedback felt holding the pin still in the air [N*m] (its weight, the pose's own estimate error):
    what a touch is felt against."""
    vals = []
    for _ in range(round(BASE_S / DECIDE_DT_S)):
        yield
        vals.append(op.p.felt_nm)
    return float(np.median(vals))


def _touchdown_pose(op, yaw, above, base, out):
    """Lower slowly until contact is felt; the hand's height then [m] (None: nothing felt)."""
    z = above[2]
    for _ in range(round(TOUCH_MAX_M / TOUCH_SPEED_M_S / DECIDE_DT_S)):
        z -= TOUCH_SPEED_M_S * DECIDE_DT_S
        op.aim(down_pose(yaw, [*above[:2], z]))
        yield
        if op.p.felt_nm - base > TOUCH_FELT_NM:
            zt = float(hand_pose(op)[2, 3])
            out["felt"].append({"t": round(op.p.t, 2), "by": "feedback", "what": "touch",
                                "height_mm": round(zt * 1e3, 1), "base_nm": round(base, 3)})
            return zt
    return None


def _regulate(op, depth: float, base: float, felt_target: float) -> float:
    return float(np.clip(depth + DEPTH_KI * (felt_target - (op.p.felt_nm - base)) * DECIDE_DT_S,
                         *DEPTH_RANGE_M))


def _push_home(op, yaw, z_touch, base, felt_target):
    """Hold where the pin dropped and push on the felt push until the hand stops sinking: 'seated' deep in
    the bore, 'jammed' (after lifting a little) when it stopped short."""
    xy = hand_pose(op)[:2, 3].copy()
    depth = max(0.0, z_touch - float(hand_pose(op)[2, 3]))
    window = round(STILL_S / DECIDE_DT_S)
    zs: list[float] = []
    for _ in range(round(PUSH_S / DECIDE_DT_S)):
        depth = _regulate(op, depth, base, felt_target * 1.3)
        op.aim(down_pose(yaw, [*xy, z_touch - depth]))
        yield
        z = float(hand_pose(op)[2, 3])
        zs.append(z)
        still = len(zs) > window and abs(zs[-window] - z) < STILL_M and op.p.felt_nm - base > TOUCH_FELT_NM
        if still:
            if z_touch - z > HOME_M:
                return "seated"
            break
    for k in range(round(0.4 / DECIDE_DT_S)):  # stopped short: ease off and lift a little, then again
        op.aim(down_pose(yaw, [*xy, z_touch - depth + 0.002 * k / round(0.4 / DECIDE_DT_S)]))
        yield
    return "jammed"
