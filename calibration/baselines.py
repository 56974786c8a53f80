"""External joint torque baselines NEXT is compared against (paper appendix, "External Joint Torque Estimation
Baseline Implementation"), as pure functions over (N, n) arrays:

- filic_residual: tau_ext = tau_m - (M(q) qdd + C(q, qd) qd + g(q)), qdd by finite differences of q_dot,
  low-pass filtered (first order, causal by default so it matches what runs online).
- momentum_observer: generalised-momentum disturbance observer, p = M(q) qd,
  d(p_hat)/dt = tau_m - C qd - g + Mdot qd + r, r = K_o (p - p_hat); integrated with explicit Euler on the
  samples' own time steps (irregular t allowed). Uses Mdot = C + C^T, so -C qd + Mdot qd = C^T qd.
- raw_torque: tau_ext = tau_m (no model at all).
- ridge: linear regression of tau_m on sin q, cos q, q_dot, tanh(q_dot / v0), q_cmd - q (for logs without an
  arm model, e.g. the UR5 current logs); tau_ext = tau_m - prediction.

Sign convention (the paper's, used everywhere in calibration/): tau_ext = tau_m - tau_f, the extra torque the
motors spend because of contact. With M qdd + C qd + g = tau_m + J^T F (F: wrench the environment applies to
the robot) that is tau_ext = -J^T F. The momentum observer's r estimates J^T F, so it is returned negated.
Rigid-body terms come from a pinocchio model (pin.Model). Units: q [rad], qd [rad/s], tau [N*m], t [s].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin


def lowpass(x: np.ndarray, t: np.ndarray, cutoff_hz: float, zero_phase: bool = False) -> np.ndarray:
    """First-order low-pass along axis 0 with per-sample alpha = dt / (dt + 1 / (2 pi fc)).
    zero_phase=True runs it forward and backward (offline only: no lag, not causal)."""
    x = np.asarray(x, float)
    if cutoff_hz <= 0:
        return x.copy()
    tau_c = 1.0 / (2 * np.pi * cutoff_hz)
    dt = np.diff(np.asarray(t, float), prepend=t[0])
    alpha = dt / (dt + tau_c)

    def run(a, al):
        y = np.empty_like(a)
        y[0] = a[0]
        for k in range(1, len(a)):
            y[k] = y[k - 1] + al[k] * (a[k] - y[k - 1])
        return y

    y = run(x, alpha)
    if zero_phase:
        y = run(y[::-1], np.r_[alpha[1:], alpha[:1]][::-1])[::-1]
    return y


def finite_difference_acceleration(t: np.ndarray, qd: np.ndarray, cutoff_hz: float = 10.0,
                                   zero_phase: bool = False) -> np.ndarray:
    """qdd [rad/s^2] = backward difference of q_dot over t, then low-pass filtered at cutoff_hz."""
    t = np.asarray(t, float)
    qdd = np.zeros_like(np.asarray(qd, float))
    qdd[1:] = np.diff(qd, axis=0) / np.diff(t)[:, None]
    return lowpass(qdd, t, cutoff_hz, zero_phase)


def rigid_body_torque(model: pin.Model, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """M(q) qdd + C(q, qd) qd + g(q) [N*m] for every row (recursive Newton-Euler)."""
    data = model.createData()
    return np.stack([pin.rnea(model, data, q[k], qd[k], qdd[k]) for k in range(len(q))])


def filic_residual(model: pin.Model, t: np.ndarray, q: np.ndarray, qd: np.ndarray, tau_m: np.ndarray,
                   accel_cutoff_hz: float = 10.0, zero_phase: bool = False) -> np.ndarray:
    """FILIC-style model residual tau_m - tau_f [N*m] with filtered finite-difference acceleration."""
    qdd = finite_difference_acceleration(t, qd, accel_cutoff_hz, zero_phase)
    return np.asarray(tau_m, float) - rigid_body_torque(model, q, qd, qdd)


def momentum_observer_step(integral: np.ndarray, r: np.ndarray, p: np.ndarray, p0: np.ndarray,
                           tau_m: np.ndarray, beta: np.ndarray, dt_s: float,
                           k_o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One step of the generalised-momentum observer (De Luca; the paper's DO baseline), shared by the batch
    baseline below and the streaming teleop estimator.

    Model: M q_ddot + C q_dot + g = tau_m + tau_env, p = M q_dot, p_dot = tau_m - beta + tau_env with
    beta = g - C^T q_dot. integral += dt (tau_m - beta + r); r = K_o (p - p0 - integral) -> tau_env, i.e.
    tau_ext = -r (first order, rate K_o [1/s]). Returns (integral, r)."""
    integral = integral + dt_s * (tau_m - beta + r)
    return integral, k_o * (p - p0 - integral)


def momentum_observer_step_floats(integral: list[float], r: list[float], p: list[float], p0: list[float],
                                  tau_m: list[float], g: list[float], ctq: list[float], dt_s: float,
                                  k_o: list[float]) -> tuple[list[float], list[float]]:
    """momentum_observer_step with beta = g - ctq (ctq = C^T q_dot [N*m]) on plain floats, bit for bit
    (the same float64 operations in the same order; tests/test_observer_floats.py): the streaming observer
    runs it at the loop's rate, where seven numpy calls on six values cost more than this loop."""
    out_i: list[float] = []
    out_r: list[float] = []
    for i0, r0, pj, p0j, tm, gj, cj, k in zip(integral, r, p, p0, tau_m, g, ctq, k_o, strict=True):
        i1 = i0 + dt_s * ((tm - (gj - cj)) + r0)
        out_i.append(i1)
        out_r.append(k * ((pj - p0j) - i1))
    return out_i, out_r


def momentum_observer(model: pin.Model, t: np.ndarray, q: np.ndarray, qd: np.ndarray, tau_m: np.ndarray,
                      gain: float | np.ndarray = 50.0) -> np.ndarray:
    """Discrete momentum observer; returns tau_ext = -r_k [N*m] (sign convention above); gain K_o [1/s]
    (scalar or per joint). r_0 = 0 (p_hat starts at the measured momentum). Euler step on t's spacing;
    K_o * dt < 1 keeps the discrete update stable (a first-order filter of the true disturbance
    with time constant 1/K_o)."""
    t, q, qd, tau_m = (np.asarray(a, float) for a in (t, q, qd, tau_m))
    k_o = np.broadcast_to(np.asarray(gain, float), (q.shape[1],))
    data = model.createData()
    p = np.empty_like(q)  # generalised momentum M(q) qd
    beta = np.empty_like(q)  # g - C^T qd  (= C qd + g - Mdot qd)
    for k in range(len(t)):
        m = pin.crba(model, data, q[k])
        p[k] = (np.triu(m) + np.triu(m, 1).T) @ qd[k]  # pinocchio fills the upper triangle only
        c = pin.computeCoriolisMatrix(model, data, q[k], qd[k])
        beta[k] = pin.computeGeneralizedGravity(model, data, q[k]) - c.T @ qd[k]
    r = np.zeros_like(q)
    integral = np.zeros(q.shape[1])
    for k in range(1, len(t)):  # explicit Euler: the integrand of the previous sample
        integral, r[k] = momentum_observer_step(integral, r[k - 1], p[k], p[0], tau_m[k - 1], beta[k - 1],
                                                t[k] - t[k - 1], k_o)
    return -r


def raw_torque(tau_m: np.ndarray) -> np.ndarray:
    """The measured torque itself as the 'estimate' (what naive force feedback would use)."""
    return np.asarray(tau_m, float).copy()


@dataclass
class RidgeModel:
    """tau ~ features @ w + b, features standardised; fitted in closed form."""

    w: np.ndarray
    b: np.ndarray
    f_mean: np.ndarray
    f_std: np.ndarray
    v0: float

    def predict(self, q, qd, q_cmd) -> np.ndarray:
        f = (ridge_features(q, qd, q_cmd, self.v0) - self.f_mean) / self.f_std
        return f @ self.w + self.b


def ridge_features(q, qd, q_cmd, v0: float = 0.05) -> np.ndarray:
    """[sin q, cos q, q_dot, tanh(q_dot / v0), q_cmd - q] per sample; v0 [rad/s] sets the friction knee."""
    q, qd, q_cmd = (np.asarray(a, float) for a in (q, qd, q_cmd))
    return np.concatenate([np.sin(q), np.cos(q), qd, np.tanh(qd / v0), q_cmd - q], axis=1)


def fit_ridge(q, qd, q_cmd, tau, alpha: float = 1e-3, v0: float = 0.05) -> RidgeModel:
    """Closed-form ridge fit of tau (N, n) on ridge_features (alpha: L2 weight on standardised features)."""
    f = ridge_features(q, qd, q_cmd, v0)
    mean, std = f.mean(0), f.std(0)
    std = np.where(std < 1e-6, np.inf, std)  # a feature constant in the training data gets no weight
    z = (f - mean) / std
    tau = np.asarray(tau, float)
    b = tau.mean(0)
    w = np.linalg.solve(z.T @ z + alpha * len(z) * np.eye(z.shape[1]), z.T @ (tau - b))
    return RidgeModel(w=w, b=b, f_mean=mean, f_std=std, v0=v0)


def ridge_residual(model: RidgeModel, q, qd, q_cmd, tau) -> np.ndarray:
    return np.asarray(tau, float) - model.predict(q, qd, q_cmd)
