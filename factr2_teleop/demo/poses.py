"""The demo task's leader poses for any arm (SIMULATED twin).

The task constants of factr2_teleop/demo/task.py (ABOVE, PRESS) are joint angles laid out for the Piper's
joint layout on its table scene (leaders gello_piper / gello_yam). An arm with another layout (an imported
UR5: its q2 = 1.6 rad points the upper arm into the table) gets poses derived from its own description and
its scene's table: above the table = its home pose (clear of the table) turned about the base axis so that
the tool centre point is over the table's middle direction (the imported UR5's home tool sits beyond the
table edge, behind its base), the press target = that point moved straight down to PRESS_DEPTH_M below the
table top (so the hand keeps pushing in contact, as the Piper's target 0.1 rad beyond the surface does),
solved by damped least squares on the description's kinematics. Its generated GELLO leader copies the
follower's joints one to one, so these follower joint angles are the leader's.
"""

from __future__ import annotations

import numpy as np

PRESS_DEPTH_M = 0.03  # press target below the table top [m] (UR5 twin, 10 s lockstep demo: the hand pushes
# 1.05 N into the table at 0.03 m, -0.18 N at 0.01 m: it loses contact)
IK_DAMPING = 1e-3  # damped least squares [m^2]: no jump near a singular wrist
IK_TOL_M = 1e-4


def press_pose(fk, jacobian, q_start: np.ndarray, drop_m: float, iterations: int = 50) -> np.ndarray:
    """Joint angles [rad] that move the tool centre point straight down by drop_m [m] from its position at
    q_start, orientation free. fk(q) -> 4x4 pose, jacobian(q) -> (6, n) (rows vx vy vz ...), base-aligned
    axes with z up."""
    q = np.asarray(q_start, float).copy()
    target = fk(q)[:3, 3] - np.array([0.0, 0.0, drop_m])
    for _ in range(iterations):
        err = target - fk(q)[:3, 3]
        if np.linalg.norm(err) < IK_TOL_M:
            break
        j = jacobian(q)[:3]
        q = q + j.T @ np.linalg.solve(j @ j.T + IK_DAMPING * np.eye(3), err)
    return q


def table_top(world_model) -> tuple[float, np.ndarray] | None:
    """(height of the top [m], (x, y) of its centre [m]) of the scene's box named "table", or None."""
    import mujoco

    g = mujoco.mj_name2id(world_model, mujoco.mjtObj.mjOBJ_GEOM, "table")
    if g < 0:
        return None
    return float(world_model.geom_pos[g][2] + world_model.geom_size[g][2]), world_model.geom_pos[g][:2].copy()


def turned_over(q: np.ndarray, tcp_xy: np.ndarray, centre_xy: np.ndarray) -> np.ndarray:
    """q [rad] with the first (base, vertical) joint turned so that the tool's direction from the base axis
    points at the table centre's."""
    out = np.asarray(q, float).copy()
    turn = np.arctan2(centre_xy[1], centre_xy[0]) - np.arctan2(tcp_xy[1], tcp_xy[0])
    out[0] += (turn + np.pi) % (2 * np.pi) - np.pi
    return out


def derived_task_poses(arm, world_model) -> tuple[np.ndarray, np.ndarray]:
    """(above, press) [rad] for the follower `arm` (hardware.arms.ArmDescription) in its twin world (the arm
    base at the world origin, as in every scene)."""
    from hardware.arms.dynamics import ArmDynamics

    dyn = ArmDynamics(arm)
    lo, hi = arm.limits.q_min, arm.limits.q_max
    above = np.asarray(arm.q_home, float).copy()
    top = table_top(world_model)
    top_z, centre = top if top is not None else (0.0, None)
    if centre is not None:
        turned = np.clip(turned_over(above, dyn.fk(above)[:2, 3], centre), lo, hi)
        tcp = dyn.fk(turned)[:3, 3]
        if abs(np.arctan2(tcp[1], tcp[0]) - np.arctan2(centre[1], centre[0])) < 0.05:  # joint 1 is vertical
            above = turned
    drop = dyn.fk(above)[2, 3] - top_z + PRESS_DEPTH_M
    return above, np.clip(press_pose(dyn.fk, dyn.jacobian, above, drop), lo, hi)
