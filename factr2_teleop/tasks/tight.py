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
3. Search by pecks: lift the tip clear, move over the next point of a hexagonal grid around the touch
   (nearest first), press a few mm below the touch height with the hand's compliance (the lean on the joint
   error off) and rest; a hand that rests DROP_M lower than it rested on the fixture top has dropped into the
   bore (the chamfer leads a tip in from CAPTURE_M off the axis). A grid without a drop: lift, look again,
   search again.
4. Push it home on a felt push (over the baseline, like wipe.py's strokes); seated when the hand has stopped
   sinking for STILL_S deep in the bore (stop on force); a stop short of that depth is a jam: lift a little
   and push again.
5. Let go, lift.
"""

from __future__ import annotations

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.scripts import DECIDE_DT_S, best_down_yaw, go_joints, grip, move, wait, yaw_of
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
# The search pecks: lift the tip clear, move over the next point of a hexagonal grid around the seen bore
# (nearest first), press down, and see whether the hand sinks. A spiral slid on the fixture top did not
# work: the follower's own compliance against the sliding friction (1-2 N at a 3-6 N push) held the hand
# within ~2 mm while the leader traced +-5 mm (measured, dev seed 51), so the tip never crossed the chamfer.
PECK_SPACING_M = 0.0032  # m: hexagonal grid pitch (every point of the disc within 1.85 mm of a grid point,
# inside the chamfer's CAPTURE_M of 2.2 mm, 0.35 mm left for the hand's placing error)
PECK_R_M = 0.0115  # m: the widest point searched (the seen bore is off by 2.8-3.6 mm std per axis)
PECK_ABOVE_M = 0.005  # m: the hand aimed this far above its touch height while moving between points (the
# touch is felt with the hand already pressing, the follower lags a fast lift: 3.5 mm did not lift the tip)
PECK_PRESS_M = 0.005  # m: aimed this far below the touch height on each peck
PECK_LIFT_S, PECK_MOVE_S, PECK_DOWN_S, PECK_HOLD_S = 0.2, 0.25, 0.3, 0.3  # s: the aim's lift, move over
# the next point, down to hover over it, rest after the press (the lift and the hover then wait on the arm)
PECK_CLEAR_M = 0.002  # m: the hand this far above its touch height (FK) before it moves: the tip clear
PECK_HOVER_M = 0.0025  # m: over the point, the hand this far above its touch height, held still, then pressed
# (1 mm: the sagging hand put the tip on the top while it still moved, dev seed 56)
PECK_PRESS_S = 0.4  # s: the press from the hover (0.2 s: the impact slid the pin up in the fingers, the
# hand rested 0.5 mm lower each peck and read as a drop after six, dev seed 31)
PECK_WAIT_S = 0.8  # s: the longest wait for the tip clear, or for the hand still over the point
PECK_STILL_M_S = 0.01  # m/s: the hand (FK) moving slower than this is still (the pin has stopped swinging)
PECK_KI = 2.0  # 1/s: how fast the aim's height correction takes up the still arm's sag (the lean is off)
PECK_CORR_MAX_M = 0.006  # m: the largest correction of the aim (height; across: the landing's)
PECK_LAND_GAIN = 0.6  # of a landing's miss, aimed against on the next press: the contact's feedback and the
# leader's stiction shift the pressed hand 1-3 mm (dev seeds 56, 57), mostly the same way; an integrator on
# the hand's position across (stick-slip) hunted 1.5-2.6 mm around the point instead (dev seed 57)
PECK_REACH_M = 0.0019  # m: a landing searches the bore centres this close (CAPTURE_M less 0.3 mm: the tip's
# swing in the fingers against the hand's measured pose)
PECK_TRIES = 2  # pecks aimed at one grid point at most
PECK_LEFT = 0.3  # a grid point is pecked (again) while this share of the disc it stands for is unsearched
# (0.1: more pecks again at the same point; Monte Carlo of next_peck with 1.1 mm landing scatter: 90 % found
# within 19 pecks at 0.3, 23 at 0.1)
DROP_M = 0.002  # m: resting this much lower than on the fixture top (the last pecks' rests): it is in
SINK_WINDOW_S, SINK_M, SINK_WAIT_S = 0.1, 0.0003, 0.8  # s, m, s: after a peck's rest, a hand still
# sinking more than SINK_M per SINK_WINDOW_S is waited for, at most SINK_WAIT_S
DROP_FIRST_M = 0.003  # m: the first peck, with no rest on the top to compare: this far below the touch height
# (pressed on the top it rests 0.5-2 mm below it, measured)
PECK_REF_N = 3  # pecks: the rests on the top a peck is compared with (their median; few: the pin may
# creep up in the fingers, and the rests with it)
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


def hand_pose(op) -> np.ndarray:
    """Where the gripper is, from the follower's reported joints (FK): the operator's own arm, not the twin's
    truth."""
    return op.fk(op.p.q_follower)


def peck_grid(spacing_m: float, radius_m: float) -> np.ndarray:
    """Points [m] (N, 2) of a hexagonal grid of pitch spacing_m within radius_m of the origin, nearest first
    (then by angle); the origin first. Every point of the disc is within spacing_m / sqrt(3) of one (pure)."""
    n = int(np.ceil(radius_m / spacing_m)) + 1
    i, j = np.meshgrid(np.arange(-2 * n, 2 * n + 1), np.arange(-n, n + 1))
    pts = np.column_stack([(i + 0.5 * j).ravel() * spacing_m, (j * np.sqrt(3) / 2).ravel() * spacing_m])
    r = np.hypot(*pts.T)
    pts, r = pts[r <= radius_m + 1e-12], r[r <= radius_m + 1e-12]
    order = np.lexsort((np.arctan2(pts[:, 1], pts[:, 0]), np.round(r, 9)))
    return pts[order]


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


def _down(yaw: float, p) -> np.ndarray:
    return K.pose(K.down_rotation(yaw), p)


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
    yield from move(op, _down(yaw, T[:3, 3] + [0, 0, 0.06]), dur(0.9), T_from=T)
    return out


def _ready(op, pin, dur):
    """Bring the arm over the pin in joint space, from an IK solved from the middle of the joint ranges (the
    elbow up): from the stretched start pose the Cartesian aim stalls on the joint limits."""
    T = _down(0.0, np.asarray(pin, float) + [0, 0, TIP_BELOW_EE_M + READY_ABOVE_M])
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
    yield from move(op, _down(yaw, grasp_p + [0, 0, 0.07]), dur(1.8), bump=bump)
    yield from move(op, _down(yaw, grasp_p), dur(1.0))
    yield from wait(op, 0.4)
    yield from grip(op, 1.0, dur(0.5))
    yield from wait(op, 0.5)
    sight.forget("pin")  # from here on, a detection of the pin is a new look
    yield from move(op, _down(yaw, grasp_p + [0, 0, LIFT_M]), dur(0.9))
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
        yield from move(op, _down(yaw, above), dur(2.0), bump=bump)
        yield from wait(op, 0.3)
        base = yield from _felt_base(op)
        z_touch = yield from _touch_down(op, yaw, above, base, out)
        if z_touch is None:
            return "lost"
        op.servo_on = False  # from here the push comes from the hand's compliance (wipe.py)
        if z_touch < above[2] - APPROACH_ABOVE_M - STRAIGHT_IN_M:
            status = "dropped"  # felt far below the top: it went in on the way down
            z_touch = above[2] - APPROACH_ABOVE_M  # the hand's height with the tip at the top, as seen
        else:
            t0 = op.p.t
            status = yield from _pecks(op, yaw, hand_pose(op)[:2, 3].copy(), z_touch, out)
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
        yield from move(op, _down(yaw, T[:3, 3] + [0, 0, 0.02]), dur(0.6), T_from=T)
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


def _touch_down(op, yaw, above, base, out):
    """Lower slowly until contact is felt; the hand's height then [m] (None: nothing felt)."""
    z = above[2]
    for _ in range(round(TOUCH_MAX_M / TOUCH_SPEED_M_S / DECIDE_DT_S)):
        z -= TOUCH_SPEED_M_S * DECIDE_DT_S
        op.aim(_down(yaw, [*above[:2], z]))
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


def _aim_for(op, yaw, T_from, p_to, seconds: float):
    """Move the hand in a straight line to p_to over `seconds` (linear: the pecks are short)."""
    n = max(1, round(seconds / DECIDE_DT_S))
    for k in range(1, n + 1):
        op.aim(_down(yaw, T_from + (np.asarray(p_to) - T_from) * k / n))
        yield


def aim_correction(corr, aimed, reached, dt: float, ki: float, limit: float) -> np.ndarray:
    """The operator's correction of where it aims [m]: the arm's own error (aimed - reached, FK) integrated
    at ki [1/s], bounded to +-limit (pure). Aiming at point + correction puts a sagging hand on the point, as
    a person watching their own arm pushes until it is there."""
    e = np.asarray(aimed, float) - np.asarray(reached, float)
    return np.clip(np.asarray(corr, float) + ki * dt * e, -limit, limit)


def disc_points(radius_m: float, pitch_m: float = 0.0004) -> np.ndarray:
    """Where the bore's centre may be [m] (N, 2): a fine grid over the searched disc (pure)."""
    return peck_grid(pitch_m, radius_m)


def next_peck(grid: np.ndarray, cand: np.ndarray, landed: list, tried: np.ndarray) -> int | None:
    """Index of the next grid point to peck (pure): the first (nearest the touch) not tried PECK_TRIES times
    whose own share of the disc (the candidate centres cand nearer to it than to any other point, within
    pitch / sqrt(3)) is still more than PECK_LEFT unsearched, a candidate being searched once a peck landed
    (measured) within PECK_REACH_M of it. A peck that lands off its point searches what it landed near; the
    point is pecked again only if what it stands for is left. None: the disc is searched."""
    left = np.ones(len(cand), bool)
    for p in landed:
        left &= np.hypot(*(cand - p).T) > PECK_REACH_M
    d = np.linalg.norm(cand[:, None, :] - grid[None], axis=2)
    owner = np.where(d.min(axis=1) <= PECK_SPACING_M / np.sqrt(3) + 1e-9, np.argmin(d, axis=1), -1)
    for i in range(len(grid)):
        if tried[i] >= PECK_TRIES:
            continue
        mine = owner == i
        if mine.any() and left[mine].mean() > PECK_LEFT:
            return i
    return None


def _hold(op, yaw, target, corr, z_done, seconds: float):
    """Aim at target + corr until the arm's own pose (FK) shows the hand still (and above z_done when given),
    at most `seconds`; the height correction takes up the still arm's sag (aim_correction)."""
    prev = hand_pose(op)[:3, 3]
    for _ in range(max(1, round(seconds / DECIDE_DT_S))):
        op.aim(_down(yaw, target + corr))
        yield
        p = hand_pose(op)[:3, 3]
        still = np.linalg.norm(p - prev) <= PECK_STILL_M_S * DECIDE_DT_S
        prev = p
        if still and (z_done is None or p[2] >= z_done):
            break
        if still:
            corr = aim_correction(corr, target * [0, 0, 1], p * [0, 0, 1], DECIDE_DT_S, PECK_KI,
                                  PECK_CORR_MAX_M)
    return corr


def _pecks(op, yaw, centre, z_touch, out):
    """Peck around centre (where the touch was felt), each peck checked on the arm's own measured pose: lift
    until the hand is PECK_CLEAR_M above the touch height (the tip clear of the top), move over the next
    point, hover until still, press PECK_PRESS_M below the touch and rest. Where it rested (FK) is what it
    searched (next_peck), and its miss is aimed against on the next press. 'dropped' when the hand rests
    DROP_M lower than it rests on the fixture top (the median of the last pecks' rests: the pin may creep
    up in the fingers; the first peck, where the touch was, against the touch height itself), 'none' when
    the disc is searched."""
    z_up, z_press = z_touch + PECK_ABOVE_M, z_touch - PECK_PRESS_M
    rests: list[float] = []
    landed: list[np.ndarray] = []
    grid = centre + peck_grid(PECK_SPACING_M, PECK_R_M)
    cand = centre + disc_points(PECK_R_M)
    tried = np.zeros(len(grid), int)
    corr, land = np.zeros(3), np.zeros(2)  # m: the aim's height correction, and the landing's (across)
    aimed = np.array([*centre, z_touch])  # the hand's last aim
    while (i := next_peck(grid, cand, landed, tried)) is not None:
        tried[i] += 1
        out["pecks"] += 1
        up = np.array([*aimed[:2], z_up])
        yield from _aim_for(op, yaw, aimed, up + corr, PECK_LIFT_S)
        corr = yield from _hold(op, yaw, up, corr, z_touch + PECK_CLEAR_M, PECK_WAIT_S)
        xy = grid[i]
        over = np.array([*(xy + land), z_up])
        yield from _aim_for(op, yaw, up + corr, over + corr, PECK_MOVE_S)
        hover = np.array([*over[:2], z_touch + PECK_HOVER_M])
        yield from _aim_for(op, yaw, over + corr, hover + corr, PECK_DOWN_S)
        corr = yield from _hold(op, yaw, hover, corr, None, PECK_WAIT_S)
        aimed = np.array([*over[:2], z_press])
        yield from _aim_for(op, yaw, hover + corr, aimed, PECK_PRESS_S)
        yield from wait(op, PECK_HOLD_S)
        rest = yield from _settle(op)
        landed.append(hand_pose(op)[:2, 3].copy())
        out.setdefault("peck_miss_mm", []).append(round(float(np.hypot(*(landed[-1] - xy))) * 1e3, 2))
        land = np.clip(land + PECK_LAND_GAIN * (xy - landed[-1]), -PECK_CORR_MAX_M, PECK_CORR_MAX_M)
        top = float(np.median(rests[-PECK_REF_N:])) if rests else z_touch - DROP_FIRST_M + DROP_M
        if rest < top - DROP_M:
            out["felt"].append({"t": round(op.p.t, 2), "by": "own arm", "what": "drop",
                                "sunk_mm": round((top - rest) * 1e3, 1), "peck": len(rests) + 1})
            return "dropped"
        rests.append(rest)
    return "none"


def _settle(op):
    """Wait while the hand is still sinking (a tip sliding down the chamfer takes the lagging follower
    longer than a peck's rest: traced on dev seed 54, a tip 1.5 mm into the chamfer was lifted out by the
    next peck), at most SINK_WAIT_S; the hand's height then [m]."""
    zs = [float(hand_pose(op)[2, 3])]
    n = round(SINK_WINDOW_S / DECIDE_DT_S)
    for _ in range(round(SINK_WAIT_S / DECIDE_DT_S)):
        if len(zs) > n and zs[-n - 1] - zs[-1] < SINK_M:
            break
        yield
        zs.append(float(hand_pose(op)[2, 3]))
    return zs[-1]


def _push_home(op, yaw, z_touch, base, felt_target):
    """Hold where the pin dropped and push on the felt push until the hand stops sinking: 'seated' deep in
    the bore, 'jammed' (after lifting a little) when it stopped short."""
    xy = hand_pose(op)[:2, 3].copy()
    depth = max(0.0, z_touch - float(hand_pose(op)[2, 3]))
    window = round(STILL_S / DECIDE_DT_S)
    zs: list[float] = []
    for _ in range(round(PUSH_S / DECIDE_DT_S)):
        depth = _regulate(op, depth, base, felt_target * 1.3)
        op.aim(_down(yaw, [*xy, z_touch - depth]))
        yield
        z = float(hand_pose(op)[2, 3])
        zs.append(z)
        still = len(zs) > window and abs(zs[-window] - z) < STILL_M and op.p.felt_nm - base > TOUCH_FELT_NM
        if still:
            if z_touch - z > HOME_M:
                return "seated"
            break
    for k in range(round(0.4 / DECIDE_DT_S)):  # stopped short: ease off and lift a little, then again
        op.aim(_down(yaw, [*xy, z_touch - depth + 0.002 * k / round(0.4 / DECIDE_DT_S)]))
        yield
    return "jammed"
