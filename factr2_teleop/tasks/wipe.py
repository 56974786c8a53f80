"""Wiping demonstrations: close the gripper, lower it onto the mark until the table is felt, then stroke
across the mark row by row while keeping the felt push (the leader's force feedback) near a target.

Pressing is where the feedback does the work: the operator stops leaning on the follower's joint error
(op.servo_on off) and regulates how deep it aims below the surface by what it feels, as the paper's
operators regulate their push by the feedback torque; the contact force follows from the hand's compliance.
"""

from __future__ import annotations

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.scripts import DECIDE_DT_S, FELT_NM, aim_tool, grip, move, wait
from hardware.sim.tasks import wipe as W

PUSH_FELT_NM = (0.15, 0.3)  # N*m: the range of felt push a demonstration aims for (drawn per episode)
DEPTH_KI = 0.05  # m per (N*m * s): how fast the aimed depth follows the felt push error
DEPTH_RANGE_M = (-0.004, 0.03)  # m: aimed depth below the surface, bounds
ROWS_Y = (-0.0225, -0.0075, 0.0075, 0.0225)  # m: stroke rows across the mark (its frame)
EDGE_X = 0.034  # m: strokes run from -EDGE_X to +EDGE_X along the mark
TOUCH_DOWN_S = 4.0  # s: the most a careful touch-down may take


def _on_mark(params, lx: float, ly: float, z: float, yaw: float) -> np.ndarray:
    c, s = np.cos(params["area_yaw"]), np.sin(params["area_yaw"])
    p = np.asarray(params["area_pos"], float) + [c * lx - s * ly, s * lx + c * ly, 0.0]
    return K.pose(K.down_rotation(yaw), p + [0, 0, z + W.TIP_OFFSET_M])


def wipe(op, params: dict, rng: np.random.Generator):
    speed = rng.uniform(0.8, 1.3)
    out = op.log = {"gave_up": False, "retries": 0, "felt": []}
    felt_target = rng.uniform(*PUSH_FELT_NM)
    yield
    yaw = float(params["area_yaw"])
    x0 = -EDGE_X if rng.random() < 0.5 else EDGE_X  # which end it starts from
    bump = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.0, 0.05)])
    yield from grip(op, 1.0, 0.4)
    yield from move(op, _on_mark(params, x0, ROWS_Y[0], 0.04, yaw), 1.8 * speed, bump=bump)

    def tip():
        return op.p.obs["tip_pos"]

    # touch down: lower slowly until the table is felt
    z = 0.04
    for _ in range(round(TOUCH_DOWN_S / DECIDE_DT_S)):
        z -= 0.02 * DECIDE_DT_S
        aim_tool(op, _on_mark(params, x0, ROWS_Y[0], z, yaw), seen=tip)
        yield
        if op.p.felt_nm > FELT_NM:
            out["felt"].append({"t": round(op.p.t, 2), "by": "feedback",
                                "height_mm": round(tip()[2] * 1e3, 1)})
            break
    op.servo_on = False  # from here the push is regulated by feel, not by leaning on the joint error
    depth = max(0.0, -z)
    x = x0
    for k, row in enumerate(ROWS_Y):
        x_to = -x
        n = max(1, round(2.0 * speed * rng.uniform(0.9, 1.1) / DECIDE_DT_S))
        y_from = ROWS_Y[k - 1] if k else row
        for i in range(1, n + 1):
            a = i / n
            ly = y_from + min(1.0, 4 * a) * (row - y_from)  # step over to the new row at the start
            lx = x + a * (x_to - x)
            depth = float(np.clip(depth + DEPTH_KI * (felt_target - op.p.felt_nm)
                                  * DECIDE_DT_S, *DEPTH_RANGE_M))
            aim_tool(op, _on_mark(params, lx, ly, -depth, yaw), seen=tip)
            yield
        x = x_to
    op.servo_on = True
    T = op.ee_pose_des()
    yield from move(op, K.pose(T[:3, :3], T[:3, 3] + [0, 0, 0.06]), 0.9 * speed)
    yield from grip(op, 0.0, 0.3)
    yield from wait(op, 0.2)
    return out
