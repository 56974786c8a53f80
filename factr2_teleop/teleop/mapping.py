"""Joint maps between frames: leader joints -> follower joints, and leader joints -> the leader's model.

A JointMap is affine per joint: q_b[j] = k[j] * q_a[index[j]] + offset[j] with k = sign * scale. It is used
twice, with separate parameters, because forks found the model's joint frame and the follower's differ:
  - leader -> follower (targets), and its transpose for torques going back (feedback);
  - leader -> leader model (gravity compensation, Jacobian), and back for the model's torques.
Torques map back by virtual work (tau_a . dq_a = tau_b . dq_b): tau_a[index[j]] += k[j] * tau_b[j].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hardware.errors import ConfigError
from hardware.params import PerJoint, per_joint


@dataclass
class JointMapConfig:
    """index: for each joint of frame b, the joint of frame a that drives it (None: identity).
    sign: +1/-1 per b joint; scale: motion scaling (1 = same angle); offset_rad: added after scaling [rad].
    gripper_scale / gripper_offset: b gripper = offset + scale * a gripper (leader trigger 0..1 -> follower
    stroke [m]); gripper_min / gripper_max: clamp of the mapped gripper."""

    index: list[int] | None = None
    sign: PerJoint = 1.0
    scale: PerJoint = 1.0
    offset_rad: PerJoint = 0.0
    gripper_scale: float = 1.0
    gripper_offset: float = 0.0
    gripper_min: float = -np.inf
    gripper_max: float = np.inf


class JointMap:
    """Affine per-joint map from frame a (n_a joints) to frame b (n_b joints)."""

    def __init__(self, cfg: JointMapConfig, n_a: int, n_b: int, where: str = "mapping"):
        idx = list(range(n_b)) if cfg.index is None else [int(i) for i in cfg.index]
        if len(idx) != n_b or any(i < 0 or i >= n_a for i in idx) or len(set(idx)) != len(idx):
            raise ConfigError(f"index {idx} must list {n_b} distinct joints in 0..{n_a - 1}",
                              where=f"{where}.index", fix="one leader joint per follower joint")
        sign = per_joint(cfg.sign, n_b, f"{where}.sign")
        if not np.all(np.abs(sign) == 1.0):
            raise ConfigError(f"sign must be +1 or -1, got {sign.tolist()}", where=f"{where}.sign",
                              fix="use 1 or -1 per joint")
        scale = per_joint(cfg.scale, n_b, f"{where}.scale", positive=True)
        self.cfg, self.n_a, self.n_b = cfg, n_a, n_b
        self.index = np.asarray(idx, dtype=int)
        self.k = sign * scale
        self.offset = per_joint(cfg.offset_rad, n_b, f"{where}.offset_rad")
        # joint j -> joint j for every joint (the usual rig): the same products without the fancy index and
        # the scatter (500 Hz, three maps a tick); sign, scale and offset still apply
        self._in_order = n_a == n_b and idx == list(range(n_b))
        # ... and with every k 1.0 (sign +1, scale 1): 1.0 * x is x, bit for bit (-0.0, inf and NaN too), so
        # the product is left out (forward adds the offset, torque_back copies)
        self._unit = self._in_order and bool(np.all(self.k == 1.0))

    @classmethod
    def identity(cls, n: int) -> JointMap:
        return cls(JointMapConfig(), n, n)

    def forward(self, q_a: np.ndarray) -> np.ndarray:
        """Positions a -> b [rad]."""
        if self._unit:
            return np.asarray(q_a, dtype=float) + self.offset
        if self._in_order:
            return self.k * np.asarray(q_a, dtype=float) + self.offset
        return self.k * np.asarray(q_a, dtype=float)[self.index] + self.offset

    def forward_velocity(self, qd_a: np.ndarray) -> np.ndarray:
        """Velocities a -> b [rad/s]."""
        return self.k * np.asarray(qd_a, dtype=float)[self.index]

    def backward(self, q_b: np.ndarray, fill: float = np.nan) -> np.ndarray:
        """Positions b -> a [rad]; a joints no b joint depends on get `fill`."""
        q_a = np.full(self.n_a, fill)
        q_a[self.index] = (np.asarray(q_b, dtype=float) - self.offset) / self.k
        return q_a

    def backward_velocity(self, qd_b: np.ndarray) -> np.ndarray:
        """Velocities b -> a [rad/s]; a joints no b joint depends on get 0."""
        qd_a = np.zeros(self.n_a)
        qd_a[self.index] = np.asarray(qd_b, dtype=float) / self.k
        return qd_a

    def torque_back(self, tau_b: np.ndarray) -> np.ndarray:
        """Torques b -> a [N*m] by virtual work; unmapped a joints get 0."""
        if self._unit:
            t = np.array(tau_b, dtype=float)  # a new array, as the product was (broadcast: the product)
            return t if t.shape == self.k.shape else self.k * t
        if self._in_order:
            return self.k * np.asarray(tau_b, dtype=float)
        tau_a = np.zeros(self.n_a)
        tau_a[self.index] = self.k * np.asarray(tau_b, dtype=float)
        return tau_a

    def gripper_forward(self, g_a: float) -> float | None:
        """Gripper a -> b, clamped; None when a has no finite gripper reading (keep the b gripper)."""
        if g_a is None or not math.isfinite(g_a):
            return None
        c = self.cfg  # floats: min/max, not np.clip (500 Hz)
        return float(min(max(c.gripper_offset + c.gripper_scale * g_a, c.gripper_min), c.gripper_max))
