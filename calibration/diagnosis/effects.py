"""The library of declared effects. Each is linear in its coefficients once its few nonlinear settings
(`hyper`: a period, a Stribeck velocity, a backlash width, the other joint of a coupling) are fixed; the trace
finds those settings from the residual, the least-squares fit finds the coefficients.

All effects act on the equation of one joint j (0-based) and are in the units of the data (N*m or A).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FAMILIES = ("coulomb_friction", "viscous_friction", "stribeck_friction", "position_periodic", "backlash",
            "position_spring", "drift", "current_offset", "torque_constant_scale", "delay", "coupling")

SIGN_EPS = 0.01  # rad/s: tanh(qd / SIGN_EPS) stands for sign(qd) without the jump at qd = 0


@dataclass
class Effect:
    family: str
    joint: int
    hyper: dict = field(default_factory=dict)
    coef: np.ndarray | None = None
    ref: np.ndarray | None = None  # frozen rigid-part parameters (torque_constant_scale, delay)

    @property
    def key(self) -> tuple:
        return (self.family, self.joint, tuple(sorted((k, round(v, 9) if isinstance(v, float) else v)
                                                      for k, v in self.hyper.items())))

    @property
    def slot(self) -> tuple:
        """Two effects with the same slot are the same thing: only one of them is kept in a model."""
        return (self.family, self.joint, self.hyper.get("other_joint"), self.hyper.get("source"))

    def features(self, d) -> np.ndarray:
        """(N, k) columns on a Design `d` (stacked segments, see greybox.Design)."""
        return np.atleast_2d(_FEATURES[self.family](self, d).T).T

    def params(self) -> dict:
        """Human-readable parameters (units of the data; rad, s)."""
        c = [float(x) for x in (self.coef if self.coef is not None else [np.nan] * 3)]
        h, f = self.hyper, self.family
        if f == "coulomb_friction":
            return {"fc": c[0]}
        if f == "viscous_friction":
            return {"fv": c[0]}
        if f == "stribeck_friction":
            return {"fs_extra": c[0], "v_stribeck_rad_s": h["vs"]}
        if f == "position_periodic":
            return {"amplitude": float(np.hypot(c[0], c[1])), "period_rad": h["period_rad"],
                    "phase": float(np.arctan2(c[1], c[0]))}
        if f == "backlash":
            return {"offset": c[0], "width_rad": h["width_rad"]}
        if f == "position_spring":
            k = c[0]
            q0 = h["q_ref"] - c[1] / k if abs(k) > 1e-12 else float("nan")
            return {"stiffness_per_rad": k, "rest_position_rad": q0}
        if f == "drift":
            unit = "per_min" if h["source"] == "time" else "per_degC"
            return {"source": h["source"], f"rate_{unit}": c[0]}
        if f == "current_offset":
            return {"offset": c[0]}
        if f == "torque_constant_scale":
            return {"scale": 1.0 + c[0]}
        if f == "delay":  # c * (pred(t - s) - pred(t)) ~ -c * s * pred'(t): a lag of c * s
            return {"delay_s": c[0] * h["shift_s"], "shift_s": h["shift_s"]}
        if f == "coupling":
            return {"other_joint": h["other_joint"], "viscous": c[0], "coulomb": c[1]}
        return {"coef": c}

    def implausible(self) -> str:
        """Why the fitted parameters are not physical ("" when they are): a torque-constant scale outside
        0.5-2, a negative / over-half-second delay, or a spring of negative stiffness (a passive elastic
        element restores; an anti-spring is a gravity or K error fitted through the wrong feature) is another
        effect fitted through the wrong feature."""
        if self.coef is None:
            return ""
        p = self.params()
        if self.family == "torque_constant_scale" and not 0.5 <= p["scale"] <= 2.0:
            return f"scale {p['scale']:.3g} outside 0.5..2"
        if self.family == "delay" and not 0.0 <= p["delay_s"] <= 0.5:
            return f"delay {p['delay_s']:.3g} s outside 0..0.5 s"
        if self.family == "position_spring" and p["stiffness_per_rad"] < 0.0:
            return f"negative stiffness {p['stiffness_per_rad']:.3g} N*m/rad"
        return ""

    @classmethod
    def from_json(cls, d: dict, ref: np.ndarray | None = None) -> Effect:
        """An effect from a report's `effects` entry ({effect, joint, hyper}); coefficients are refitted.
        ref: the rigid parameters torque_constant_scale and delay scale (their feature is the rigid part)."""
        fam, joint = d.get("effect"), d.get("joint")
        if fam not in FAMILIES or not isinstance(joint, int) or joint < 0:
            raise ValueError(f"not an effect: {d!r}")
        return cls(fam, joint, dict(d.get("hyper") or {}), None,
                   ref if fam in ("torque_constant_scale", "delay") else None)

    def to_json(self) -> dict:
        return {"effect": self.family, "joint": self.joint, "params": self.params(),
                "hyper": {k: v for k, v in self.hyper.items()}}


def play_operator(q: np.ndarray, width: float) -> np.ndarray:
    """Backlash (play) hysteresis: (q - p) / width in [-1, 1], p dragged along when q moves more than
    `width` [rad] away. +1 while moving up, -1 while moving down, ramping over 2*width after a reversal and
    holding its value while the joint stands still (unlike Coulomb friction, which follows sign(qd))."""
    out = np.empty_like(q)
    p = q[0]
    for i, x in enumerate(q):
        if x - p > width:
            p = x - width
        elif p - x > width:
            p = x + width
        out[i] = (x - p) / width
    return out


def _per_segment(d, fn) -> np.ndarray:
    return np.concatenate([fn(a, b) for a, b in d.bounds])


def _sincos(x: np.ndarray) -> np.ndarray:
    return np.stack([np.sin(x), np.cos(x)], 1)


def _rigid(e: Effect, d) -> np.ndarray:
    idx, cols = d.base[e.joint]
    return cols @ e.ref[idx]


_FEATURES = {
    "coulomb_friction": lambda e, d: np.tanh(d.qd[:, e.joint] / SIGN_EPS),
    "viscous_friction": lambda e, d: d.qd[:, e.joint],
    "stribeck_friction": lambda e, d: np.tanh(d.qd[:, e.joint] / SIGN_EPS)
    * np.exp(-((d.qd[:, e.joint] / e.hyper["vs"]) ** 2)),
    "position_periodic": lambda e, d: _sincos(2 * np.pi * d.q[:, e.joint] / e.hyper["period_rad"]),
    "backlash": lambda e, d: _per_segment(
        d, lambda a, b: play_operator(d.q[a:b, e.joint], e.hyper["width_rad"])),
    "position_spring": lambda e, d: np.stack([d.q[:, e.joint] - e.hyper["q_ref"], np.ones(len(d.t))], 1),
    "drift": lambda e, d: (d.t / 60.0 if e.hyper["source"] == "time"
                           else d.temp[:, e.joint] - e.hyper["temp_ref"]),
    "current_offset": lambda e, d: np.ones(len(d.t)),
    "torque_constant_scale": _rigid,
    "delay": lambda e, d: _per_segment(
        d, lambda a, b: _lagged(d.t[a:b], _rigid(e, d)[a:b], e.hyper["shift_s"])),
    "coupling": lambda e, d: np.stack([d.qd[:, e.hyper["other_joint"]],
                                       np.tanh(d.qd[:, e.hyper["other_joint"]] / SIGN_EPS)], 1),
}


def _lagged(t: np.ndarray, x: np.ndarray, shift_s: float) -> np.ndarray:
    """x(t - shift) - x(t) on a possibly irregular clock (held at the first value before the start). A shift
    rather than a derivative: the rigid prediction carries M(q) qdd, and differentiating that noise would bias
    the fitted lag toward zero (errors in the regressor)."""
    return np.interp(t - shift_s, t, x) - x
