"""Tare on grasp: take a held object's load out of the contact score (pure functions on arrays).

NEXT models the arm's free-space dynamics without a payload. Once the gripper holds an object, the object's
weight is an external torque for the whole carry, so ||tau_ext||_1 stays raised although nothing is touched.
Tare estimates that load over a short stretch of free motion right after the grasp and subtracts it until
the release:

    held      the fingers are blocked by an object: the measured stroke s is wider than the commanded one c by
              at least HOLD_GAP_M, starting once s has stood still (|ds/dt| <= SETTLE_M_S) with that gap for
              SETTLE_S (not a closing transient, nor a close command the fingers have not started on yet)
              and lasting while the gap stays (an open command, or fingers that close on nothing, end it);
              stretches shorter than MIN_HOLD_S are dropped
    window    free motion after the grasp: from the first held sample at which the arm has moved MOVE_RAD
              (||q - q_grasp||_2) from where the fingers settled (the lift: the object is off the table) for
              WINDOW_S, within the held stretch
    load      tau_load(q) = Y(q) theta, theta by least squares over the window's finite samples. Y: the arm's
              gravity regressor of a point mass on the last link (`payload`: the load follows the
              configuration), parametrised about the gripper's centre point, where a held object sits: mass
              m [kg] there and first moment m*(c - c_grip) [kg*m]; directions the window shows at under RCOND
              of the best-shown one are not fitted (minimum norm: the centre stays at the gripper's along
              what a near-still window cannot tell, e.g. the gravity direction). Or Y = I (`bias`: a
              constant per-joint torque [N*m])
    checks    a stretch stays untared when its fit cannot be a load (`plausible(theta)` gives the reason, e.g.
              a negative payload mass: the window held a contact) or when the tare does not make the held
              stretch quieter (median score not lowered: the "load" is the estimator's noise)
    tared     tau_ext - tau_load on the held stretch (grasp to release), tau_ext elsewhere

The regressor and the check are passed in (q (K, n) [rad] -> Y (K, n, p) [N*m per unit parameter]; theta ->
reason), so this module stays free of kinematics (policies.labels.tare_recording builds them from the arm
description with calibration.diagnosis's payload regressor).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

TARE_METHODS = ("payload", "bias", "off")
HOLD_GAP_M = 0.002  # stroke wider than commanded by this much: the fingers stand on an object [m]
SETTLE_M_S = 0.01  # stroke speed under which the fingers have stopped closing [m/s]
SETTLE_SPAN_S = 0.05  # the stroke speed is taken over this span (one-sample differences are noise) [s]
SETTLE_S = 0.2  # the fingers stand still on the object this long before it counts as held [s]
MIN_HOLD_S = 0.3  # shorter held stretches are chatter [s]
MOVE_RAD = 0.02  # joint-space distance from the grasp configuration that marks the lift [rad]
WINDOW_S = 1.0  # free motion used to estimate the load [s]
MIN_WINDOW = 10  # fewer finite samples in the window: no estimate, no tare for that stretch
RCOND = 0.03  # directions the window shows at under 3 % of the best-shown one stay at the prior (min. norm)

Regressor = Callable[[np.ndarray], np.ndarray]  # q (K, n) [rad] -> Y (K, n, p)
Plausible = Callable[[np.ndarray], str]  # theta -> why it cannot be a load ("" when it can)


def _latch(on: np.ndarray, off: np.ndarray) -> np.ndarray:
    """State per sample: set by `on`, cleared by `off` (off wins on a tie), else kept; starts cleared."""
    event = np.where(off, 0, np.where(on, 1, -1))
    idx = np.where(event >= 0, np.arange(len(event)), -1)
    last = np.maximum.accumulate(idx) if len(idx) else idx
    return np.where(last >= 0, event[np.maximum(last, 0)] == 1, False)


def stretches(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index pairs of the True runs of a bool array."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def held_mask(t: np.ndarray, stroke: np.ndarray, command: np.ndarray, gap_m: float = HOLD_GAP_M,
              settle_m_s: float = SETTLE_M_S, min_s: float = MIN_HOLD_S) -> np.ndarray:
    """(N,) bool: the gripper holds an object (module doc). t [s] ascending; stroke: measured gripper stroke,
    command: commanded stroke, both [m] on the times t (NaN: no gripper / no command -> not held)."""
    t = np.asarray(t, float)
    s, c = np.asarray(stroke, float), np.asarray(command, float)
    if not (t.shape == s.shape == c.shape and t.ndim == 1):
        raise ValueError(f"t, stroke and command must be (N,) alike, got {t.shape}, {s.shape}, {c.shape}")
    gap = s - c >= gap_m  # NaN compares False: no hold without both signals
    back = np.searchsorted(t, t - SETTLE_SPAN_S, side="left")
    dt = t - t[back]
    with np.errstate(invalid="ignore", divide="ignore"):
        speed = np.where(dt > 0, np.abs(s - s[back]) / np.where(dt > 0, dt, 1.0), np.inf)
    still = gap & (speed <= settle_m_s)
    on = np.zeros(len(t), bool)
    for i0, i1 in stretches(still):  # still long enough: held from the sample that completes SETTLE_S
        k = int(np.searchsorted(t[i0:i1], t[i0] + SETTLE_S, side="left")) + i0
        if k < i1:
            on[k] = True
    held = _latch(on, ~gap)
    for i0, i1 in stretches(held):
        if t[i1 - 1] - t[i0] < min_s:
            held[i0:i1] = False
    return held


def tare_window(t: np.ndarray, q: np.ndarray, i0: int, i1: int, move_rad: float = MOVE_RAD,
                window_s: float = WINDOW_S) -> tuple[int, int] | None:
    """[start, stop) of the free motion that tells the load of the held stretch [i0, i1): from the first
    sample at which q [rad] is move_rad from q[i0], for window_s [s], clipped at i1. None: the arm never
    moved while holding (nothing was lifted)."""
    q = np.asarray(q, float)
    moved = np.linalg.norm(q[i0:i1] - q[i0], axis=1) >= move_rad
    if not moved.any():
        return None
    k = i0 + int(np.argmax(moved))
    stop = int(np.searchsorted(t, t[k] + window_s, side="left"))
    return k, min(max(stop, k + 1), i1)


def bias_regressor(q: np.ndarray) -> np.ndarray:
    """Y = I per sample (K, n, n): a constant per-joint torque [N*m]."""
    q = np.asarray(q, float)
    return np.broadcast_to(np.eye(q.shape[1]), (len(q), q.shape[1], q.shape[1]))


def about_point(Y: np.ndarray, c: np.ndarray) -> np.ndarray:
    """A point payload's columns (K, n, 4) for (m [kg], m*c [kg*m]) re-centred on a point c [m] of the same
    frame: columns for (m, m*(c_obj - c)), i.e. [Y_m + Y_mc c, Y_mc]. The minimum-norm fit then puts the
    object's centre at c along what the window cannot see (the gravity direction of a still pose)."""
    Y = np.asarray(Y, float)
    return np.concatenate([Y[..., :1] + Y[..., 1:4] @ np.asarray(c, float)[:, None], Y[..., 1:4]], -1)


def from_point(theta: np.ndarray, c: np.ndarray) -> np.ndarray:
    """about_point's parameters back to (m [kg], m*c_obj [kg*m])."""
    theta = np.asarray(theta, float)
    return np.r_[theta[0], theta[1:4] + theta[0] * np.asarray(c, float)]


def fit_load(Y: np.ndarray, tau: np.ndarray, rcond: float = RCOND) -> np.ndarray | None:
    """theta minimising sum_k ||tau_k - Y_k theta||^2 over the samples whose tau is finite (minimum norm over
    directions with singular values below rcond times the largest); None with fewer than MIN_WINDOW."""
    Y, tau = np.asarray(Y, float), np.asarray(tau, float)
    ok = np.isfinite(tau).all(axis=1) & np.isfinite(Y).all(axis=(1, 2))
    if ok.sum() < MIN_WINDOW:
        return None
    A = Y[ok].reshape(-1, Y.shape[2])
    theta, *_ = np.linalg.lstsq(A, tau[ok].reshape(-1), rcond=rcond)
    return theta


@dataclass
class TareResult:
    """The load taken out of tau_ext: load (N, n) [N*m] (0 outside held stretches and on untared ones),
    held (N,) bool, and per held stretch its [start, stop), window (or None), theta (or None: not estimated)
    and why it was not tared ("" when it was)."""

    load: np.ndarray
    held: np.ndarray
    stretches: list[tuple[int, int]] = field(default_factory=list)
    windows: list[tuple[int, int] | None] = field(default_factory=list)
    thetas: list[np.ndarray | None] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)


def always(theta: np.ndarray) -> str:
    """Every theta is a load (the bias method: any constant torque is)."""
    return ""


def held_load(t: np.ndarray, tau_ext: np.ndarray, q: np.ndarray, held: np.ndarray,
              regressor: Regressor = bias_regressor, plausible: Plausible = always,
              move_rad: float = MOVE_RAD, window_s: float = WINDOW_S) -> TareResult:
    """The held object's load per sample (module doc): for each held stretch, theta fitted on its free-motion
    window, tau_load = Y(q) theta over the whole stretch, unless the checks reject it. tau_ext (N, n) [N*m],
    q (N, n) [rad] on times t."""
    tau, q = np.asarray(tau_ext, float), np.asarray(q, float)
    if tau.ndim != 2 or q.shape != tau.shape or len(t) != len(tau) or len(held) != len(tau):
        raise ValueError(f"t (N,), tau_ext (N, n), q (N, n) and held (N,) must agree: got {np.shape(t)}, "
                         f"{tau.shape}, {q.shape}, {np.shape(held)}")
    out = TareResult(np.zeros_like(tau), np.asarray(held, bool).copy())
    for i0, i1 in stretches(out.held):
        win = tare_window(t, q, i0, i1, move_rad, window_s)
        theta = fit_load(regressor(q[win[0]:win[1]]), tau[win[0]:win[1]]) if win else None
        why = "no free motion to estimate it on" if theta is None else plausible(theta)
        if not why:
            load = np.einsum("knp,p->kn", regressor(q[i0:i1]), theta)
            raw, new = np.abs(tau[i0:i1]).sum(1), np.abs(tau[i0:i1] - load).sum(1)
            if np.isfinite(raw).any() and np.nanmedian(new) < np.nanmedian(raw):
                out.load[i0:i1] = load
            else:
                why = "does not make the carry quieter"
        out.stretches.append((i0, i1))
        out.windows.append(win)
        out.thetas.append(theta)
        out.skipped.append(why)
    return out


def tared(tau_ext: np.ndarray, load: np.ndarray) -> np.ndarray:
    """tau_ext - load [N*m] (NaN stays NaN: no estimate)."""
    return np.asarray(tau_ext, float) - np.asarray(load, float)
