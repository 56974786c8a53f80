"""Tight insert's search for the bore by pecks (SIMULATED operator; factr2_teleop/tasks/tight.py runs it).

Each peck is checked on the arm's own measured pose (FK of the follower's reported joints), never on the
twin's truth: lift the tip clear, move over the next point of a hexagonal grid around the touch (nearest
first), hover until still, press a few mm below the touch height and rest; a hand that rests DROP_M lower
than it rested on the fixture top has dropped into the bore. The grid, the choice of the next point and the
aim's correction are pure functions.
"""

from __future__ import annotations

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.scripts import DECIDE_DT_S, wait

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


def down_pose(yaw: float, p) -> np.ndarray:
    """The hand pointing down at yaw [rad], at p [m] (a 4x4 pose)."""
    return K.pose(K.down_rotation(yaw), p)


def aim_line(op, yaw, T_from, p_to, seconds: float):
    """Move the hand in a straight line to p_to over `seconds` (linear: the pecks are short)."""
    n = max(1, round(seconds / DECIDE_DT_S))
    for k in range(1, n + 1):
        op.aim(down_pose(yaw, T_from + (np.asarray(p_to) - T_from) * k / n))
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
        op.aim(down_pose(yaw, target + corr))
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


def pecks(op, yaw, centre, z_touch, out):
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
        yield from aim_line(op, yaw, aimed, up + corr, PECK_LIFT_S)
        corr = yield from _hold(op, yaw, up, corr, z_touch + PECK_CLEAR_M, PECK_WAIT_S)
        xy = grid[i]
        over = np.array([*(xy + land), z_up])
        yield from aim_line(op, yaw, up + corr, over + corr, PECK_MOVE_S)
        hover = np.array([*over[:2], z_touch + PECK_HOVER_M])
        yield from aim_line(op, yaw, over + corr, hover + corr, PECK_DOWN_S)
        corr = yield from _hold(op, yaw, hover, corr, None, PECK_WAIT_S)
        aimed = np.array([*over[:2], z_press])
        yield from aim_line(op, yaw, hover + corr, aimed, PECK_PRESS_S)
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
