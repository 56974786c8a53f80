"""The identified prior for logs in motor current: an arm description corrected on the data, with a
current-per-torque scale per joint fitted together with the inertial corrections (docs/arms_import.md).

Model, per joint j: i_j = s_j * tau_j(q, q_dot, q_ddot; theta_0 + d_theta, friction) [A], where tau is the
identified prior of calibration.next.prior (RNEA of the description with its inertial correction d_theta,
armature, friction, ripple) and s_j [A per N*m] is 1 / (torque constant x gear ratio) of joint j. The
product is bilinear, so it is fitted by alternation: s from a least-squares fit of the current on the
description's torque (+ friction), then the identified prior on i / s, then s on that prior's torque,
SCALE_ITERATIONS times.

What is identifiable (docs/arms_import.md): one common factor stays free. (s alpha, theta / alpha, friction /
alpha) predicts the same currents for every alpha > 0 -- the link masses of the distal links appear in every
proximal joint's torque, so the ratios s_j / s_k are identified, the overall scale is not. The fit pins it
by pulling d_theta toward the description (the CAD masses set the scale): a payload or link mass in kg, or a
torque in N*m, is then only as right as the CAD total. A known torque constant (s_j given) or one known mass
(a payload of known kg) fixes alpha; `anchor_scale` applies either.

Streaming: s * PriorStream(i / s): the identified prior runs in N*m inside and this wrapper converts at its
edges. The fit's low-pass is linear (s * F(i / s - prediction) = F(i - s * prediction)); the estimate's
adaptive one is not, and it sees the residual in N*m, the unit its EST_BETA is tuned in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.next.prior import Prior, fit_prior, pinocchio_model
from calibration.next.prior_base import FRICTION_VEL, TorquePrior

KIND = "identified-current"
SCALE_ITERATIONS = 3  # alternations of (scale, inertial correction); the scale moves < 1 % after the second


@dataclass
class ScaledPrior(TorquePrior):
    """inner: the identified prior in N*m; scale (n,) [A per N*m]: current = scale * torque."""

    inner: Prior
    scale: np.ndarray
    kind: str = KIND

    @property
    def arm(self) -> str:
        return self.inner.arm

    @property
    def uses_temperature(self) -> bool:
        return self.inner.uses_temperature

    def stream(self, rate_hz: float | None = None) -> ScaledStream:
        return ScaledStream(self, rate_hz)

    def to_dict(self) -> dict:
        return {"kind": KIND, "version": 1, "scale": np.asarray(self.scale).tolist(),
                "inner": self.inner.to_dict()}

    @classmethod
    def from_dict(cls, d: dict, n_joints: int | None = None) -> ScaledPrior:
        if d.get("kind") != KIND or d.get("version") != 1:
            raise ValueError(f"current-scaled prior kind/version {d.get('kind')!r}/{d.get('version')!r}")
        inner = Prior.from_dict(d["inner"], n_joints)
        scale = np.asarray(d["scale"], float).reshape(-1)
        if len(scale) != len(inner.ripple_period) or not np.all(np.isfinite(scale)) or np.any(scale == 0):
            raise ValueError(f"current-scaled prior scale {scale.tolist()}")
        return cls(inner, scale)


class ScaledStream:
    """ScaledPrior one sample at a time (the PriorStream interface, in A)."""

    def __init__(self, p: ScaledPrior, rate_hz: float | None = None):
        self.p, self._inner = p, p.inner.stream(rate_hz)

    @property
    def missing_temperature(self) -> bool:
        return self._inner.missing_temperature

    def reset(self) -> None:
        self._inner.reset()

    def update(self, q, qd, tau, temperature=None, dt: float | None = None) -> np.ndarray:
        s = self.p.scale
        return s * self._inner.update(q, qd, np.asarray(tau, float) / s, temperature, dt)


def _scale_fit(torque: list[np.ndarray], current: list[np.ndarray], qd: list[np.ndarray]) -> np.ndarray:
    """Per joint, s from current ~ s * torque + coulomb * tanh(qd / v) + viscous * qd + offset (least
    squares; friction columns soak up what the torque model lacks so that s is not biased by it)."""
    tau, cur, v = (np.concatenate(x) for x in (torque, current, qd))
    s = np.zeros(tau.shape[1])
    for j in range(tau.shape[1]):
        a = np.stack([tau[:, j], np.tanh(v[:, j] / FRICTION_VEL), v[:, j], np.ones(len(v))], 1)
        s[j] = np.linalg.lstsq(a, cur[:, j], rcond=None)[0][0]
    if np.any(~np.isfinite(s)) or np.any(np.abs(s) < 1e-9):
        raise ValueError(f"current-per-torque scale not identifiable from these runs (s = {s.tolist()}): a "
                         "joint did not move or its torque does not show in its current")
    return s


def _model_torque(p: Prior, run) -> np.ndarray:
    """The identified prior's own prediction [N*m] (not the filtered tau_f part) at every sample."""
    from calibration.next.prior import PriorStream, _columns

    t, q, qd = (np.asarray(x, float) for x in run[:3])
    s = PriorStream(p)
    coef = p.coefficients()
    dts = np.diff(t, prepend=t[0])
    out = np.empty_like(q)
    for k in range(len(t)):
        rn, reg, terms, _ = s._midpoint_parts(q[k], qd[k], np.zeros(q.shape[1]), None, dts[k])
        out[k] = rn + _columns(reg, terms) @ coef
    return out


def fit_scaled_prior(arm: str, runs: list[tuple], iterations: int = SCALE_ITERATIONS,
                     known_scale: np.ndarray | None = None) -> ScaledPrior:
    """Fit on free-motion runs (t [s], q [rad], qd [rad/s], current [A][, temperature]). known_scale
    [A per N*m] (1 / torque constant x gear, per joint): taken as given instead of fitted."""
    runs = [tuple(np.asarray(x, float) if x is not None else None for x in r) for r in runs if len(r[0]) >= 2]
    if not runs:
        raise ValueError("no data to fit the current-scaled prior on")
    currents, qds = [r[3] for r in runs], [r[2] for r in runs]
    if known_scale is not None:
        scale = np.asarray(known_scale, float)
        iterations = 1
    else:
        from hardware.arms.dynamics import ArmDynamics

        dyn = ArmDynamics(arm)
        base = [dyn.rnea_batch(r[1], r[2], np.gradient(r[2], r[0], axis=0)) for r in runs]
        scale = _scale_fit(base, currents, qds)
    inner = None
    for _ in range(iterations):
        inner = fit_prior("identified", arm, [(r[0], r[1], r[2], r[3] / scale) + tuple(r[4:5]) for r in runs])
        if known_scale is None:
            scale = scale * _scale_fit([_model_torque(inner, r) for r in runs],
                                       [c / scale for c in currents], qds)
    if known_scale is None:  # the last scale was fitted after the last prior: refit the prior with it
        inner = fit_prior("identified", arm, [(r[0], r[1], r[2], r[3] / scale) + tuple(r[4:5]) for r in runs])
    return ScaledPrior(inner, scale)


def anchor_scale(p: ScaledPrior, alpha: float) -> ScaledPrior:
    """The same predictions with the free common factor set: scale * alpha, inertial correction and
    friction / alpha (alpha from a known torque constant, s_known / s_fitted, or a known mass, m_fitted /
    m_known)."""
    inner = Prior.from_dict(p.inner.to_dict())
    m = pinocchio_model(p.arm)
    theta0 = np.concatenate([m.inertias[j].toDynamicParameters() for j in range(1, m.njoints)])
    # the full parameters scale, not the corrections: description + correction -> (that) / alpha
    inner.d_theta = (theta0 + inner.d_theta) / alpha - theta0
    for k in inner.joint:
        inner.joint[k] = inner.joint[k] / alpha
    arm0 = np.asarray(m.armature, float)
    inner.joint["d_armature"] = (arm0 + p.inner.joint["d_armature"]) / alpha - arm0
    return ScaledPrior(inner, p.scale * alpha)
