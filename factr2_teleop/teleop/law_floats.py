"""The leader law's per-tick terms on plain floats: the 500 Hz path of leader_law.LeaderLaw.step.

Each function is its leader_law counterpart (friction_dither, friction_coulomb, joint_limit_barrier,
damping_term, the sum and cap_total) on lists of 6-7 floats, bit for bit: the same float64 operations in the
same order, numpy's maximum / minimum written out (NaN wins, a tie of 0.0 and -0.0 gives the second operand:
hardware.small_vec.np_max), np.sign's 0 for +-0 and NaN for NaN. Why: on 6 values a numpy call costs
~0.5-1 us, a float operation ~30-50 ns, and the law took ~25 numpy calls a tick (issue #53).
tests/test_law_floats.py checks each against the numpy form on any floats (NaN, +-inf, -0.0).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np


def friction_dither_floats(g: list[float], q_dot: list[float], gain: list[float], min_nm: list[float],
                           v_thr: list[float], sign: list[float]) -> list[float]:
    """sign * max(gain |g|, min_nm) [N*m] on joints slower than v_thr [rad/s], else 0 (friction_dither)."""
    out = []
    for gj, v, k, m, thr, s in zip(g, q_dot, gain, min_nm, v_thr, sign, strict=True):
        if abs(v) < thr:
            a = k * abs(gj)
            out.append(s * (a if (a > m or a != a) else m))
        else:
            out.append(0.0)
    return out


def friction_coulomb_floats(q_dot: list[float], tau_c: list[float], v_thr: list[float]) -> list[float]:
    """tau_c * sign(q_dot) [N*m] once |q_dot| >= v_thr [rad/s], else 0 (friction_coulomb)."""
    out = []
    for v, c, thr in zip(q_dot, tau_c, v_thr, strict=True):
        if abs(v) >= thr:
            out.append(c * (1.0 if v > 0.0 else -1.0 if v < 0.0 else v if v != v else 0.0))
        else:
            out.append(0.0)
    return out


def barrier_floats(q: list[float], q_dot: list[float], lo: list[float], hi: list[float],
                   neg_kp: list[float], kd: list[float]) -> list[float] | None:
    """joint_limit_barrier with lo = q_min + margin, hi = q_max - margin [rad] and neg_kp = -kp; None when
    every joint is inside (the term is zero)."""
    out = None
    for j, (x, v, a, b, kp, k) in enumerate(zip(q, q_dot, lo, hi, neg_kp, kd, strict=True)):
        if x < a:
            e = a
        elif x > b:
            e = b
        else:
            continue
        if out is None:
            out = [0.0] * len(q)
        out[j] = kp * (x - e) - k * v
    return out


def scaled(k: list[float], x: list[float]) -> list[float]:
    """k * x elementwise (gravity_term with k the gain; damping_term with k = -kd)."""
    return [a * b for a, b in zip(k, x, strict=True)]


def sum_cap(terms, cap: list[float]) -> tuple[list[float], list[float], int]:
    """(sum, capped sum, joints capped) [N*m] of the term lists in order, as LeaderLaw.step adds them: from
    0.0, a non-finite sum becomes 0 (a NaN model output never reaches the leader), then clipped to +-cap."""
    total = None
    for t in terms:
        if total is None:
            total = [0.0 + x for x in t]
        else:
            total = [a + b for a, b in zip(total, t, strict=True)]
    if not all(map(math.isfinite, total)):
        total = [x if math.isfinite(x) else 0.0 for x in total]
    out, capped = [], 0
    for x, c in zip(total, cap, strict=True):
        lo = -c
        y = x if (x > lo or x != x) else lo
        y = y if (y < c or y != y) else c
        out.append(y)
        capped += y != x
    return total, out, capped


_JOINT_KEYS = ("dither_gain", "dither_min", "v_thr", "coulomb", "b_lo", "b_hi", "neg_b_kp", "b_kd",
               "neg_damp", "cap")


def law_joint_params(f) -> list[tuple[float, ...]]:
    """The law's per-joint float parameters (LeaderLaw's f) as one tuple per joint, in _JOINT_KEYS order:
    law_tau_floats' loop reads them from f["joints"] when LeaderLaw made it once (else from here)."""
    return list(zip(*(f[k] for k in _JOINT_KEYS), strict=True))


def law_tau_floats(gl, g_gain, qd, q, dither, coulomb, sign, f, ns, fb) -> tuple[list[float], int]:
    """The capped sum of the law's terms [N*m] in one pass over the joints: per joint the same float64
    operations, in the same order, as the term kernels above and sum_cap over [gravity, friction, barrier,
    null_space, damping, feedback] (bit for bit; tests/test_law_floats.py), without the six term lists.
    gl: g(q) [N*m] (None: gravity off), g_gain; qd [rad/s] (finite), q [rad] (None: barrier off); dither /
    coulomb: the friction mode (neither: off), sign: the dither's +-1 per joint; f: LeaderLaw's float
    parameters (f["joints"]: law_joint_params(f), made once); ns: the null-space term (None: zero); fb: the
    feedback term. Returns (tau, joints capped).
    The running sum t starts as 0.0 + (gravity), which is never -0.0, so adding a term that is 0.0 (a joint
    the term leaves alone) gives t itself: those additions are left out (a NaN sum becomes 0 at the end)."""
    n = len(qd)
    zeros = [0.0] * n
    grav, bar = gl is not None, q is not None
    jp = f.get("joints") or law_joint_params(f)
    isfinite = math.isfinite
    out: list[float] = []
    append = out.append
    capped = 0
    for g, k, v, x, s, nsj, fbj, (dk, dm, thr, cc, lo, hi, nkp, bkd, nd, c) in zip(
            gl if grav else zeros, g_gain, qd, q if bar else zeros, sign, zeros if ns is None else ns, fb, jp,
            strict=True):
        t = 0.0 + k * g if grav else 0.0  # gravity (0.0 + 0.0 when off, as the zeros list was)
        if dither:
            if abs(v) < thr:
                a = dk * abs(g)
                t = t + s * (a if (a > dm or a != a) else dm)
        elif coulomb and abs(v) >= thr:
            t = t + cc * (1.0 if v > 0.0 else -1.0 if v < 0.0 else v if v != v else 0.0)
        if bar:
            if x < lo:
                t = t + (nkp * (x - lo) - bkd * v)
            elif x > hi:
                t = t + (nkp * (x - hi) - bkd * v)
        t = ((t + nsj) + nd * v) + fbj
        if -c < t < c:  # finite and inside the cap: unchanged (as the clip below gives it)
            append(t)
            continue
        if not isfinite(t):
            t = 0.0
        lo_c = -c
        y = t if (t > lo_c or t != t) else lo_c
        y = y if (y < c or y != y) else c
        append(y)
        capped += y != t
    return out, capped


class LawTerms(Mapping):
    """The law's named terms [N*m] of one tick, read-only: each given as floats (or an array) and made a
    float64 array at its first read (np.asarray: an array given passes as it is). Most ticks nobody reads
    them (the demo and the terminal app read the feedback term), so the 500 Hz loop builds none: raw may
    be a function that makes the {name: floats} dict at the first read (names: their order)."""

    __slots__ = ("_raw", "_arrays", "_names")

    def __init__(self, raw, names: tuple[str, ...] | None = None):
        self._raw = raw
        self._arrays: dict = {}
        self._names = tuple(raw) if names is None else names

    def __getitem__(self, name: str) -> np.ndarray:
        a = self._arrays.get(name)
        if a is None:
            if callable(self._raw):
                self._raw = self._raw()
            a = self._arrays[name] = np.asarray(self._raw[name], dtype=float)
        return a

    def __iter__(self):
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def __repr__(self) -> str:
        return f"LawTerms({dict(self)!r})"
