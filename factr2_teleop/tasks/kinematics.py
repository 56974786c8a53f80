"""Follower-pose targets for a scripted operator: top-down gripper poses and damped least-squares IK on the
arm description (hardware.arms.dynamics: pinocchio FK and Jacobian of the ee site). Pure numpy on arrays.

Top-down pose: the gripper's approach axis (+z of the last link) points at the table, its fingers close along
the link's x axis, which makes yaw psi with world x: R = [x, y, z] with x = (cos psi, sin psi, 0),
z = (0, 0, -1), y = z cross x.
"""

from __future__ import annotations

import numpy as np

IK_DAMPING = 1e-3  # DLS damping lambda^2 [m^2]: keeps steps finite near singular poses
IK_ROT_WEIGHT_M = 0.1  # m per rad: weight of orientation error against position error


def down_rotation(yaw: float) -> np.ndarray:
    """Rotation matrix of a top-down gripper with its finger axis at `yaw` [rad] from world x."""
    c, s = np.cos(yaw), np.sin(yaw)
    x, z = np.array([c, s, 0.0]), np.array([0.0, 0.0, -1.0])
    return np.column_stack([x, np.cross(z, x), z])


def pose(R: np.ndarray, p) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def rotation_error(R: np.ndarray, R_des: np.ndarray) -> np.ndarray:
    """Axis-angle vector [rad] (world frame) that rotates R onto R_des."""
    E = R_des @ R.T
    angle = np.arccos(np.clip((np.trace(E) - 1.0) / 2.0, -1.0, 1.0))
    v = np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    if angle < 1e-9:
        return 0.5 * v
    return angle / (2.0 * np.sin(angle)) * v if np.sin(angle) > 1e-9 else np.zeros(3)


def pose_error(T: np.ndarray, T_des: np.ndarray) -> np.ndarray:
    """6-vector (position [m], orientation [rad]) from T to T_des, world frame."""
    return np.concatenate([T_des[:3, 3] - T[:3, 3], rotation_error(T[:3, :3], T_des[:3, :3])])


def ik_step(fk, jac, q: np.ndarray, T_des: np.ndarray, q_min, q_max, max_step_rad: float = 0.2) -> np.ndarray:
    """One damped least-squares step toward T_des from q (fk(q) -> 4x4, jac(q) -> 6 x n), in limits."""
    e = pose_error(fk(q), T_des)
    w = np.array([1, 1, 1, IK_ROT_WEIGHT_M, IK_ROT_WEIGHT_M, IK_ROT_WEIGHT_M])
    J = jac(q) * w[:, None]
    dq = J.T @ np.linalg.solve(J @ J.T + IK_DAMPING * np.eye(6), e * w)
    dq = np.clip(dq, -max_step_rad, max_step_rad)
    return np.clip(q + dq, q_min, q_max)


def solve_ik(fk, jac, q_seed, T_des, q_min, q_max, iters: int = 50, tol_m: float = 1e-5):
    """(q, residual 6-vector): iterate ik_step from q_seed until the error is below tol_m (rad x 0.1 m)."""
    q = np.asarray(q_seed, dtype=float).copy()
    for _ in range(iters):
        q = ik_step(fk, jac, q, T_des, q_min, q_max)
        e = pose_error(fk(q), T_des)
        if np.max(np.abs(e[:3])) < tol_m and np.max(np.abs(e[3:])) * IK_ROT_WEIGHT_M < tol_m:
            break
    return q, e
