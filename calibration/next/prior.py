"""A physics prior under NEXT: tau_f = prior(q, q_dot, q_ddot) + f_theta(history), the network trained on
what the prior leaves.

Why: from ~10 minutes of free motion the plain LSTM memorises the trajectories it saw instead of learning the
arm's structure (docs/next.md, "What limits NEXT on the twin"): it does not carry the gravity map over to
configurations it did not visit, nor the friction sign to a contact it never saw. The rigid-body equations
carry both. Kinds:

- "none": the paper's plain NEXT (f_theta learns everything).
- "description": RNEA of the arm description (masses, inertias, rotor armature) plus its joint friction
  (MJCF frictionloss as Coulomb, damping as viscous) -- what FILIC uses, with friction.
- "identified": the description corrected on the calibration data itself: a regularised least-squares fit of
  the inertial parameters' correction (pinocchio's joint-torque regressor, pulled toward zero correction, i.e.
  toward the description, where the motion does not excite a parameter), the armature's correction and a
  Coulomb + viscous friction per joint. Linear in its parameters, so it is one solve, no training.

Acceleration: the causal filtered finite difference of q_dot (calibration.baselines, cut-off
`ACCEL_CUTOFF_HZ`), offline and online alike (`PriorStream` runs the same filter one sample at a time), so
training, evaluation and the control loop see the same prior. The prior needs N*m (a torque signal); logs in
A without a torque constant get "none".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import pinocchio as pin

from calibration.baselines import finite_difference_acceleration

PRIOR_KINDS = ("none", "description", "identified")
ACCEL_CUTOFF_HZ = 20.0  # low-pass on the finite-difference acceleration [Hz] (docs/next.md: 10 -> 20 Hz)
FRICTION_VEL = 0.02  # tanh width of the identified Coulomb term [rad/s] (above the velocity noise)
PARAM_RIDGE = 1e-3  # ridge on the inertial/armature correction, relative to each column's energy
FRICTION_RIDGE = 1e-9  # friction coefficients: nearly free


@dataclass
class Prior:
    kind: str
    arm: str  # hardware.arms name or MJCF path (pinocchio model of the description)
    d_theta: np.ndarray = field(default_factory=lambda: np.zeros(0))  # inertial parameter correction, 10/body
    d_armature: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [kg*m^2] per joint
    coulomb: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [N*m] per joint
    viscous: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [N*m*s/rad] per joint
    friction_vel: float = FRICTION_VEL  # [rad/s]
    accel_cutoff_hz: float = ACCEL_CUTOFF_HZ

    def to_dict(self) -> dict:
        return {"kind": self.kind, "arm": self.arm, "friction_vel": self.friction_vel,
                "accel_cutoff_hz": self.accel_cutoff_hz,
                **{k: np.asarray(getattr(self, k)).tolist()
                   for k in ("d_theta", "d_armature", "coulomb", "viscous")}}

    @classmethod
    def from_dict(cls, d: dict, n_joints: int | None = None) -> Prior:
        """Inverse of to_dict; ValueError on an unknown kind, or (with n_joints) arrays of the wrong size or
        non-finite values."""
        if d.get("kind") not in PRIOR_KINDS[1:]:
            raise ValueError(f"prior kind {d.get('kind')!r}")
        keys = ("d_theta", "d_armature", "coulomb", "viscous")
        arrays = [np.asarray(d[k], float).reshape(-1) for k in keys]
        if n_joints is not None and [len(a) for a in arrays] != [10 * n_joints] + [n_joints] * 3:
            raise ValueError(f"prior arrays of sizes {[len(a) for a in arrays]} for {n_joints} joints")
        if not all(np.all(np.isfinite(a)) for a in arrays):
            raise ValueError("prior has non-finite parameters")
        return cls(d["kind"], d["arm"], *arrays, float(d["friction_vel"]), float(d["accel_cutoff_hz"]))


@lru_cache(maxsize=4)
def pinocchio_model(arm: str) -> pin.Model:
    from hardware.arms import load_arm

    return load_arm(arm).pinocchio_model()


def description_prior(arm: str) -> Prior:
    """RNEA + the description's joint friction (frictionloss -> Coulomb, damping -> viscous)."""
    m = pinocchio_model(arm)
    n = m.nv
    return Prior("description", arm, np.zeros(10 * n), np.zeros(n), np.asarray(m.friction, float).copy(),
                 np.asarray(m.damping, float).copy())


def _features(m: pin.Model, d: pin.Data, q, qd, qdd, friction_vel: float) -> tuple[np.ndarray, np.ndarray]:
    """(rnea (n,), columns (n, 10 n + 3 n)): regressor | armature qdd | tanh(qd / v) | qd, per joint."""
    n = m.nv
    cols = np.zeros((n, 13 * n))
    cols[:, :10 * n] = pin.computeJointTorqueRegressor(m, d, q, qd, qdd)
    idx = np.arange(n)
    cols[idx, 10 * n + idx] = qdd
    cols[idx, 11 * n + idx] = np.tanh(qd / friction_vel)
    cols[idx, 12 * n + idx] = qd
    return pin.rnea(m, d, q, qd, qdd).copy(), cols


def _coefs(p: Prior) -> np.ndarray:
    return np.concatenate([p.d_theta, p.d_armature, p.coulomb, p.viscous])


def prior_torque(p: Prior, t: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """The prior's torque [N*m] for every sample of one run (N, n) (causal acceleration from its start)."""
    m = pinocchio_model(p.arm)
    d = m.createData()
    qdd = finite_difference_acceleration(t, qd, p.accel_cutoff_hz)
    coef = _coefs(p)
    out = np.empty_like(np.asarray(q, float))
    for k in range(len(q)):
        rn, cols = _features(m, d, q[k], qd[k], qdd[k], p.friction_vel)
        out[k] = rn + cols @ coef
    return out


def fit_prior(kind: str, arm: str, runs: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
              ) -> Prior:
    """The prior of `kind` for `arm`, fitted (for "identified") on free-motion runs (t [s], q [rad],
    qd [rad/s], tau_m [N*m])."""
    if kind == "description":
        return description_prior(arm)
    if kind != "identified":
        raise ValueError(f"prior must be one of {PRIOR_KINDS[1:]}, got {kind!r}")
    m = pinocchio_model(arm)
    d = m.createData()
    n = m.nv
    p = 13 * n
    ata, atb = np.zeros((p, p)), np.zeros(p)
    chunk = 2048  # samples per normal-equation update: memory stays small however long the run
    a = np.empty((chunk, n, p))
    y = np.empty((chunk, n))
    for t, q, qd, tau in runs:
        qdd = finite_difference_acceleration(t, qd, ACCEL_CUTOFF_HZ)
        for lo in range(0, len(t), chunk):
            k_n = min(chunk, len(t) - lo)
            for i in range(k_n):
                k = lo + i
                rn, a[i] = _features(m, d, q[k], qd[k], qdd[k], FRICTION_VEL)
                y[i] = tau[k] - rn
            a_k = a[:k_n].reshape(-1, p)
            ata += a_k.T @ a_k
            atb += a_k.T @ y[:k_n].ravel()
    energy = np.maximum(np.diag(ata), 1e-12)
    lam = np.full(p, PARAM_RIDGE)
    lam[11 * n:] = FRICTION_RIDGE
    sol = np.linalg.lstsq(ata + np.diag(lam * energy), atb, rcond=None)[0]
    if not np.all(np.isfinite(sol)):
        raise ValueError("the identified prior's least squares gave non-finite parameters (non-finite "
                         "data?); use --prior description or none")
    return Prior("identified", arm, sol[:10 * n], sol[10 * n:11 * n], sol[11 * n:12 * n], sol[12 * n:],
                 FRICTION_VEL, ACCEL_CUTOFF_HZ)


class PriorStream:
    """The prior one sample at a time at a fixed rate (the estimator's): the same causal acceleration filter
    as `prior_torque` on a uniform grid, so both agree to rounding."""

    def __init__(self, p: Prior, rate_hz: float):
        self.p = p
        self.m = pinocchio_model(p.arm)
        self.d = self.m.createData()
        self.coef = _coefs(p)
        dt = 1.0 / rate_hz
        self.alpha = dt / (dt + 1.0 / (2 * np.pi * p.accel_cutoff_hz))
        self.inv_dt = rate_hz
        self.reset()

    def reset(self) -> None:
        self._qd_prev = None
        self._qdd = None

    def update(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Prior torque [N*m] (n,) for this sample."""
        if self._qd_prev is None:
            self._qdd = np.zeros_like(qd)
        else:
            self._qdd = self._qdd + self.alpha * ((qd - self._qd_prev) * self.inv_dt - self._qdd)
        self._qd_prev = np.array(qd, float)
        rn, cols = _features(self.m, self.d, q, qd, self._qdd, self.p.friction_vel)
        return rn + cols @ self.coef
