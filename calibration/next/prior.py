"""A physics prior under NEXT: the network is trained on what the prior leaves.

Why: from ~10 minutes of free motion the plain LSTM memorises the trajectories it saw instead of learning the
arm's structure (docs/next.md, "What limits NEXT on the twin"): it does not carry the gravity map over to
configurations it did not visit, nor the friction sign to a contact it never saw. The rigid-body equations
carry both. Kinds:

- "none": the paper's plain NEXT (f_theta learns everything).
- "description": RNEA of the arm description (masses, inertias, rotor armature) plus its joint friction
  (MJCF frictionloss as Coulomb, damping as viscous) -- what FILIC uses, with friction.
- "identified": the description corrected on the calibration data itself, by one regularised least-squares
  solve (no training): the inertial parameters' correction (pinocchio's joint-torque regressor, pulled
  toward the description where the motion does not excite a parameter) and per joint the armature, Coulomb
  friction (a smooth and a sharp sign), Stribeck break-away, the torque constant's drift with motor
  temperature (when the log has temperature and the joint heated by >= 5 K) and a position-periodic
  ripple whose period is found in the residual (calibration.periodic.find_period) and kept only where it
  explains enough of it.

Filtering, the same everywhere (fit, offline evaluation, the control loop's PriorStream). The acceleration is
the backward difference of q_dot, so every other signal is taken at the same half-sample midpoint, where
tau_m - prior is an estimate of the external torque's mean over the last sample period. Filtering only the
acceleration (as FILIC does) leaves M(q) (qdd - qdd_filtered) -- the filter's lag times the jerk -- in the
residual; so the filter acts on the residual r = tau_m - prior itself (docs/next_twin.md):

- the fit weighs the residual through a fixed low-pass (`FILTER_ORDER` first-order sections at
  `ACCEL_CUTOFF_HZ`, linear, so the least-squares design is filtered column by column);
- the estimate passes an adaptive low-pass (the "1-euro" filter, Casiez et al., CHI 2012): per joint the
  cut-off is EST_MIN_HZ + EST_BETA |dr/dt| (the rate of change low-passed at EST_DERIV_HZ). In free motion
  the residual is noise around 0 and the cut-off stays low; when a contact starts or ends the residual
  moves fast and the cut-off rises, so the edge is not smeared over tens of ms. With EST_BETA = 0 it is the
  fixed low-pass (how priors saved before these fields were estimated).

NEXT with a prior gives tau_ext = F(tau_m - prior) - f_theta, written here as a prediction of tau_m:
prior_torque = tau_m - F(tau_m - prior), so callers keep tau_ext = tau_m - tau_f. The prior needs N*m (a
torque signal); logs in A get it through calibration.next.scaled_prior (a current-per-torque scale per
joint). The filter constants and the TorquePrior interface live in calibration.next.prior_base.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import pinocchio as pin

from calibration.next.prior_base import (  # noqa: F401  (re-exported: the filter constants' old home)
    ACCEL_CUTOFF_HZ,
    EST_BETA,
    EST_DERIV_HZ,
    EST_MIN_HZ,
    FILTER_ORDER,
    FRICTION_VEL,
    SHARP_VEL,
    Lowpass,
    TorquePrior,
)

ARM_KINDS = ("description", "identified")  # the kinds this module fits (they need the arm description)
STRIBECK_VEL = 0.05  # decay speed of the Stribeck break-away torque [rad/s] (typical 0.01-0.1)
PARAM_RIDGE = 1e-3  # ridge on the inertial/armature/temperature terms, relative to each column's energy
FRICTION_RIDGE = 1e-9  # friction and ripple coefficients: nearly free
TEMP_MIN_SPAN_K = 5.0  # a joint gets a temperature term only when its calibration spans this much [K]
RIPPLE_MIN_PERIOD = 2 * np.pi / 200  # shortest ripple period searched [rad] (200 cycles per revolution)
RIPPLE_MIN_FRACTION = 0.02  # a ripple is kept when it explains this much of its joint's residual ...
RIPPLE_MIN_PEAK = 20.0  # ... and stands this far above the periodogram's median
N_JOINT_TERMS = 8  # per-joint columns: armature, coulomb, viscous, sharp, stribeck, temperature, sin, cos
JOINT_TERMS = ("d_armature", "coulomb", "viscous", "coulomb_sharp", "stribeck", "kt_temp", "ripple_sin",
               "ripple_cos")


@dataclass
class Prior(TorquePrior):
    """Coefficients: d_theta (10 per body, the inertial correction), then per joint d_armature [kg*m^2],
    coulomb, coulomb_sharp, stribeck [N*m], viscous [N*m*s/rad], kt_temp [1/K] (relative torque-constant
    drift times the description torque), ripple_sin/ripple_cos [N*m] at ripple_period [rad] (0: none);
    temp_ref [degC] (NaN: no temperature term)."""

    kind: str
    arm: str  # hardware.arms name or MJCF path (pinocchio model of the description)
    d_theta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    joint: dict[str, np.ndarray] = field(default_factory=dict)  # JOINT_TERMS -> (n,)
    ripple_period: np.ndarray = field(default_factory=lambda: np.zeros(0))
    temp_ref: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cutoff_hz: float = ACCEL_CUTOFF_HZ
    order: int = FILTER_ORDER
    est_min_hz: float = EST_MIN_HZ  # the estimate's adaptive low-pass (module docstring)
    est_beta: float = EST_BETA
    est_deriv_hz: float = EST_DERIV_HZ

    @property
    def uses_temperature(self) -> bool:
        return bool(np.any(np.isfinite(self.temp_ref)))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "arm": self.arm, "version": 2, "cutoff_hz": self.cutoff_hz,
                "order": self.order, "est_min_hz": self.est_min_hz, "est_beta": self.est_beta,
                "est_deriv_hz": self.est_deriv_hz, "d_theta": np.asarray(self.d_theta).tolist(),
                "ripple_period": np.asarray(self.ripple_period).tolist(),
                "temp_ref": [None if not np.isfinite(x) else float(x) for x in self.temp_ref],
                **{k: np.asarray(self.joint[k]).tolist() for k in JOINT_TERMS}}

    @classmethod
    def from_dict(cls, d: dict, n_joints: int | None = None) -> Prior:
        """Inverse of to_dict; ValueError on an unknown kind or version, or (with n_joints) arrays of the
        wrong size or non-finite values."""
        if d.get("kind") not in ARM_KINDS:
            raise ValueError(f"prior kind {d.get('kind')!r}")
        if d.get("version") != 2:
            raise ValueError("prior from an older version of factr2 (retrain it)")
        joint = {k: np.asarray(d[k], float).reshape(-1) for k in JOINT_TERMS}
        theta = np.asarray(d["d_theta"], float).reshape(-1)
        period = np.asarray(d["ripple_period"], float).reshape(-1)
        temp_ref = np.array([np.nan if x is None else x for x in d["temp_ref"]], float)
        arrays = [theta, period, *joint.values()]
        n = len(period)
        sizes = [len(a) for a in arrays] + [len(temp_ref)]
        if n_joints is not None and sizes != [10 * n_joints] + [n_joints] * (len(sizes) - 1):
            raise ValueError(f"prior arrays of sizes {[len(a) for a in arrays]} for {n_joints} joints")
        if not all(np.all(np.isfinite(a)) for a in arrays) or len(temp_ref) != n:
            raise ValueError("prior has non-finite or inconsistent parameters")
        order, cutoff = int(d["order"]), float(d["cutoff_hz"])
        # saved without the adaptive estimate: the fixed low-pass it was evaluated with
        est = [float(d.get("est_min_hz", cutoff)), float(d.get("est_beta", 0.0)),
               float(d.get("est_deriv_hz", EST_DERIV_HZ))]
        if not (1 <= order <= 4 and cutoff > 0 and est[0] > 0 and est[1] >= 0 and est[2] > 0
                and np.all(np.isfinite(est))):
            raise ValueError(f"prior filter order {order}, cut-offs {cutoff} Hz, {est}")
        return cls(d["kind"], d["arm"], theta, joint, period, temp_ref, cutoff, order, *est)

    def coefficients(self) -> np.ndarray:
        return np.concatenate([self.d_theta] + [self.joint[k] for k in JOINT_TERMS])

    def stream(self, rate_hz: float | None = None) -> PriorStream:
        return PriorStream(self, rate_hz)


@lru_cache(maxsize=4)
def pinocchio_model(arm: str) -> pin.Model:
    from hardware.arms import load_arm

    return load_arm(arm).pinocchio_model()


def _empty(kind: str, arm: str, n: int) -> Prior:
    return Prior(kind, arm, np.zeros(10 * n), {k: np.zeros(n) for k in JOINT_TERMS}, np.zeros(n),
                 np.full(n, np.nan))


def description_prior(arm: str) -> Prior:
    """RNEA + the description's joint friction (frictionloss -> Coulomb, damping -> viscous)."""
    m = pinocchio_model(arm)
    p = _empty("description", arm, m.nv)
    p.joint["coulomb"] = np.asarray(m.friction, float).copy()
    p.joint["viscous"] = np.asarray(m.damping, float).copy()
    return p


def _parts(m: pin.Model, d: pin.Data, p: Prior, q, qd, qdd, temp):
    """(rnea (n,), joint-torque regressor (n, 10 n), per-joint terms (8, n) in JOINT_TERMS order) at one
    sample."""
    rn = pin.rnea(m, d, q, qd, qdd).copy()
    sharp = np.tanh(qd / SHARP_VEL)
    has_period = p.ripple_period > 0
    phase = 2 * np.pi * q / np.where(has_period, p.ripple_period, 1.0)
    dtemp = np.where(np.isfinite(p.temp_ref), temp - p.temp_ref, 0.0) if temp is not None else 0.0
    stribeck = np.exp(-(qd / STRIBECK_VEL) ** 2) * sharp
    terms = np.stack((qdd, np.tanh(qd / FRICTION_VEL), qd, sharp, stribeck, rn * dtemp,
                      np.where(has_period, np.sin(phase), 0.0), np.where(has_period, np.cos(phase), 0.0)))
    return rn, pin.computeJointTorqueRegressor(m, d, q, qd, qdd), terms


def _columns(regressor: np.ndarray, terms: np.ndarray) -> np.ndarray:
    """The fit's design row (n, 10 n + 8 n): regressor | each per-joint term on its own joint's column."""
    n = regressor.shape[0]
    cols = np.zeros((n, (10 + N_JOINT_TERMS) * n))
    cols[:, :10 * n] = regressor
    idx = np.arange(n)
    for k, x in enumerate(terms):
        cols[idx, (10 + k) * n + idx] = x
    return cols


class PriorStream:
    """The prior one sample at a time: update(q, qd, tau_m[, temperature]) -> this sample's tau_f part
    [N*m] = tau_m - F(tau_m - prior) (module docstring). Over a run it equals prior_torque to
    rounding. A prior with a temperature term and no temperature given uses the reference temperature and
    sets `missing_temperature`."""

    def __init__(self, p: Prior, rate_hz: float | None = None):
        self.p = p
        self.m = pinocchio_model(p.arm)
        self.d = self.m.createData()
        self._joint = np.stack([p.joint[k] for k in JOINT_TERMS])  # (8, n), as _parts' terms
        self._needs_temperature = p.uses_temperature  # fixed for the stream: not re-derived per tick
        self.dt = None if rate_hz is None else 1.0 / rate_hz
        self.missing_temperature = False
        self.reset()

    def reset(self) -> None:
        self._prev = None
        self._lp = Lowpass(self.p.est_min_hz, self.p.order, self.p.est_beta, self.p.est_deriv_hz)

    def _midpoint_parts(self, q, qd, tau, temperature, dt: float):
        """(rnea, regressor, terms, tau_m) of this sample taken half a sample back, at the backward
        difference's own time (the first sample of a run: as is, zero acceleration)."""
        temp = None if temperature is None else np.asarray(temperature, float)
        if temp is not None and not np.all(np.isfinite(temp)):
            temp = None
        if temp is None and self._needs_temperature:
            self.missing_temperature = True
        cur = (np.asarray(q, float), np.asarray(qd, float), np.asarray(tau, float), temp)
        prev, self._prev = self._prev, cur
        if prev is None:
            q_m, qd_m, qdd, tau_m, temp_m = cur[0], cur[1], np.zeros_like(cur[1]), cur[2], temp
        else:
            q_m, qd_m, tau_m = (0.5 * (a + b) for a, b in zip(cur[:3], prev[:3]))
            qdd = (cur[1] - prev[1]) / dt
            temp_m = None if temp is None or prev[3] is None else 0.5 * (temp + prev[3])
        return *_parts(self.m, self.d, self.p, q_m, qd_m, qdd, temp_m), tau_m

    def update(self, q, qd, tau, temperature=None, dt: float | None = None) -> np.ndarray:
        dt = self.dt if dt is None else dt
        rn, reg, terms, tau_m = self._midpoint_parts(q, qd, tau, temperature, dt)
        pred = rn + reg @ self.p.d_theta + np.einsum("kj,kj->j", terms, self._joint)  # = rn + columns @ coef
        return np.asarray(tau, float) - self._lp(tau_m - pred, dt)


def prior_torque(p: TorquePrior, t: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray,
                 temperature: np.ndarray | None = None) -> np.ndarray:
    """The prior's part of tau_f for every sample of one run (N, n) [the log's units]: p.torque(...)."""
    return p.torque(t, q, qd, tau, temperature)


def _filtered_rows(p: Prior, run, chunk: int = 2048):
    """Yield (LP(rows) (k, n, P), LP(tau_m - rnea) (k, n), q (k, n)) in chunks over one run: the fit's
    design through the fit's fixed low-pass (linear: LP(rows) @ c = LP(rows @ c)), at the midpoints
    PriorStream uses."""
    t, q, qd, tau, temp = run
    n = len(p.ripple_period)
    s = PriorStream(p)
    lp = Lowpass(p.cutoff_hz, p.order)
    dts = np.diff(t, prepend=t[0])
    for lo in range(0, len(t), chunk):
        k_n = min(chunk, len(t) - lo)
        a = np.empty((k_n, n, (10 + N_JOINT_TERMS) * n))
        y = np.empty((k_n, n))
        for i in range(k_n):
            k = lo + i
            rn, reg, terms, tau_m = s._midpoint_parts(q[k], qd[k], tau[k], None if temp is None else temp[k],
                                                      dts[k])
            cols = _columns(reg, terms)
            f = lp(np.concatenate([cols.ravel(), tau_m - rn]), dts[k])
            a[i] = f[:cols.size].reshape(cols.shape)
            y[i] = f[cols.size:]
        yield a, y, q[lo:lo + k_n]


def _solve(p: Prior, runs) -> Prior:
    """Fit p's coefficients (in place) by regularised least squares on the runs' filtered rows."""
    n = len(p.ripple_period)
    npar = (10 + N_JOINT_TERMS) * n
    ata, atb = np.zeros((npar, npar)), np.zeros(npar)
    for run in runs:
        for a, y, _ in _filtered_rows(p, run):
            a2 = a.reshape(-1, npar)
            ata += a2.T @ a2
            atb += a2.T @ y.ravel()
    energy = np.maximum(np.diag(ata), 1e-12)
    lam = np.full(npar, FRICTION_RIDGE)
    lam[:11 * n] = PARAM_RIDGE  # inertial correction and armature
    k_temp = 10 + JOINT_TERMS.index("kt_temp")
    lam[k_temp * n:(k_temp + 1) * n] = PARAM_RIDGE  # temperature drift
    unused = np.diag(ata) <= 1e-12  # e.g. no ripple on a joint: coefficient 0
    sol = np.linalg.lstsq(ata + np.diag(lam * energy), atb, rcond=None)[0]
    sol[unused] = 0.0
    if not np.all(np.isfinite(sol)):
        raise ValueError("the identified prior's least squares gave non-finite parameters (non-finite "
                         "data?); use --prior description or none")
    p.d_theta = sol[:10 * n]
    for k, name in enumerate(JOINT_TERMS):
        p.joint[name] = sol[(10 + k) * n:(11 + k) * n]
    return p


def _find_ripple(p: Prior, runs) -> np.ndarray:
    """Per joint, the period [rad] of a position-periodic residual worth modelling (0: none)."""
    from calibration.periodic import find_period

    coef = p.coefficients()
    qs, rs = [], []
    for run in runs:
        for a, y, q in _filtered_rows(p, run):
            qs.append(q)
            rs.append(y - a @ coef)
    q, r = np.concatenate(qs), np.concatenate(rs)
    period = np.zeros(q.shape[1])
    for j in range(q.shape[1]):
        found = find_period(q[:, j], r[:, j], p_min=RIPPLE_MIN_PERIOD)
        if found is not None and found[1] >= RIPPLE_MIN_FRACTION and found[2] >= RIPPLE_MIN_PEAK:
            period[j] = found[0]
    return period


def fit_prior(kind: str, arm: str, runs: list[tuple]) -> Prior:
    """The prior of `kind` for `arm`, fitted (for "identified") on free-motion runs (t [s], q [rad],
    qd [rad/s], tau_m [N*m][, temperature [degC] or None]). Three passes: fit, find ripple periods in the
    residual, refit with them."""
    if kind == "description":
        return description_prior(arm)
    if kind != "identified":
        raise ValueError(f"prior must be one of {ARM_KINDS}, got {kind!r}")
    m = pinocchio_model(arm)
    runs = [tuple(np.asarray(x, float) for x in r[:4]) + (None if len(r) < 5 or r[4] is None
                                                           else np.asarray(r[4], float),)
            for r in runs if len(r[0]) >= 2]
    p = _empty("identified", arm, m.nv)
    if runs and all(r[4] is not None for r in runs):
        temps = np.concatenate([r[4] for r in runs])
        heated = np.ptp(temps, axis=0) >= TEMP_MIN_SPAN_K  # no drift is identifiable without heating
        p.temp_ref = np.where(heated, temps.mean(0), np.nan)
    p = _solve(p, runs)
    p.ripple_period = _find_ripple(p, runs)
    if np.any(p.ripple_period > 0):
        p = _solve(p, runs)
    return p
