"""Synthetic logs from a known model, for tests and benchmarks (labelled simulated wherever used).

analytic_arm: a geared planar 3R arm in a vertical plane. Gravity is exact for point-mass links; the
inertia is the reflected rotor inertia (diagonal, constant: it dominates on geared arms) plus the links'
configuration-dependent diagonal terms; motion is slow enough that Coriolis forces are below the noise. Every
term lies in the data-only basis, so with no injected effect the rigid part explains the data to the noise.
One effect of the library can be injected on one joint with known parameters.
"""

from __future__ import annotations

import numpy as np

from .data import Segment, differentiate, make_segment
from .effects import SIGN_EPS, play_operator

G = 9.81
MASS = (2.0, 1.5, 0.8)  # kg, point masses at the link ends
LENGTH = (0.35, 0.3, 0.15)  # m
ROTOR = (0.35, 0.25, 0.12)  # kg*m^2 reflected rotor inertia


def trajectory(duration_s: float, rate_hz: float, n: int, seed: int, dwell: bool = True):
    """Smooth multi-sine joint motion with pauses (the phase stops advancing now and then), so that the log
    has velocity reversals, standstills and a wide position range."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    q = np.zeros((len(t), n))
    for j in range(n):
        rate = 0.5 + 0.5 * np.tanh(3 * np.sin(2 * np.pi * t / rng.uniform(6, 11) + rng.uniform(0, 6)))
        if not dwell:
            rate = np.ones_like(t)
        phase = np.cumsum(rate) / rate_hz
        for k, w in enumerate(rng.uniform(0.3, 1.1, 3)):
            q[:, j] += (1.0 / (k + 1)) * np.sin(w * phase + rng.uniform(0, 2 * np.pi))
        q[:, j] = 0.3 * j + 0.9 * q[:, j]
    return t, q


def analytic_torque(q: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    n = q.shape[1]
    ang = np.cumsum(q, 1)
    tau = qdd * np.array(ROTOR[:n])
    for j in range(n):
        for k in range(j, n):  # link k's mass acts through the lever arm of links j..k
            lever = sum(LENGTH[m] * np.cos(ang[:, m]) for m in range(j, k + 1))
            tau[:, j] += MASS[k] * G * lever
            tau[:, j] += MASS[k] * sum(LENGTH[m] for m in range(j, k + 1)) ** 2 * 0.05 * qdd[:, j] * (
                1 + 0.3 * np.cos(q[:, (j + 1) % n]))
    return tau


def inject(effect: str | None, joint: int, t, q, qd, tau, temperature=None, **p) -> np.ndarray:
    """tau plus the named effect on `joint` (params in p, defaults below)."""
    tau = tau.copy()
    if effect is None:
        return tau
    j = joint
    if effect == "coulomb_friction":
        tau[:, j] += p.get("fc", 0.8) * np.tanh(qd[:, j] / SIGN_EPS)
    elif effect == "viscous_friction":
        tau[:, j] += p.get("fv", 1.5) * qd[:, j]
    elif effect == "stribeck_friction":
        stribeck = np.exp(-(qd[:, j] / p.get("vs", 0.05)) ** 2)
        tau[:, j] += p.get("fs", 1.2) * np.tanh(qd[:, j] / SIGN_EPS) * stribeck
    elif effect == "position_periodic":
        tau[:, j] += p.get("amplitude", 0.6) * np.sin(2 * np.pi * q[:, j] / p.get("period_rad", 0.25) + 0.4)
    elif effect == "backlash":
        tau[:, j] += p.get("offset", 0.8) * play_operator(q[:, j], p.get("width_rad", 0.02))
    elif effect == "position_spring":
        tau[:, j] += p.get("stiffness", 2.0) * (q[:, j] - 0.2)
    elif effect == "drift":
        tau[:, j] += p.get("rate_per_min", 1.0) * t / 60.0
    elif effect == "current_offset":
        tau[:, j] += p.get("offset", 0.7)
    elif effect == "torque_constant_scale":
        tau[:, j] *= p.get("scale", 1.15)
    elif effect == "delay":
        d = p.get("delay_s", 0.03)
        tau[:, j] = np.interp(t - d, t, tau[:, j])
    elif effect == "coupling":
        k = p.get("other_joint", (j + 1) % q.shape[1])
        tau[:, j] += p.get("viscous", 1.5) * qd[:, k] + p.get("coulomb", 0.5) * np.tanh(qd[:, k] / SIGN_EPS)
    else:
        raise ValueError(f"unknown effect {effect}")
    return tau


def analytic_arm(effect: str | None = None, joint: int = 1, duration_s: float = 60.0, rate_hz: float = 100.0,
                 seed: int = 0, noise: float = 0.05, name: str = "synthetic", **params) -> Segment:
    """One simulated run [N*m] of the analytic arm with `effect` injected on `joint` (simulated data)."""
    t, q = trajectory(duration_s, rate_hz, 3, seed)
    qd = differentiate(t, q, 1)
    qdd = differentiate(t, qd, 1)
    tau = inject(effect, joint, t, q, qd, analytic_torque(q, qdd), **params)
    rng = np.random.default_rng(seed + 1000)
    tau = tau + noise * rng.standard_normal(tau.shape)
    return make_segment(name, t, q, qd, tau, "N*m", qdd=qdd)


def pinocchio_arm(model, effect: str | None = None, joint: int = 1, duration_s: float = 30.0,
                  rate_hz: float = 100.0, seed: int = 0, noise: float = 0.05, name: str = "synthetic",
                  **params) -> Segment:
    """One simulated run [N*m] of a pinocchio model (inverse dynamics by RNEA) with an injected effect."""
    import pinocchio as pin

    data = model.createData()
    t, q = trajectory(duration_s, rate_hz, model.nv, seed)
    qd = differentiate(t, q, 1)
    qdd = differentiate(t, qd, 1)
    tau = np.stack([pin.rnea(model, data, q[i], qd[i], qdd[i]) for i in range(len(t))])
    tau = inject(effect, joint, t, q, qd, tau, **params)
    rng = np.random.default_rng(seed + 1000)
    return make_segment(name, t, q, qd, tau + noise * rng.standard_normal(tau.shape), "N*m", qdd=qdd)
