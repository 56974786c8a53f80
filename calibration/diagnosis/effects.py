"""The library of declared effects. Each is linear in its coefficients once its few nonlinear settings
(`hyper`: a period, a Stribeck velocity, a backlash width, the other joint of a coupling) are fixed; the trace
finds those settings from the residual, the least-squares fit finds the coefficients.

All effects act on the equation of one joint j (0-based) and are in the units of the data (N*m or A).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FAMILIES = ("coulomb_friction", "viscous_friction", "stribeck_friction", "position_periodic", "backlash",
            "position_spring", "drift", "current_offset", "torque_constant_scale", "delay", "coupling",
            "payload", "gravity_load")
# Families that act on every joint's equation with shared coefficients (features (N, n, k)); the effect's
# `joint` is the link it is attached to (the last one: a payload sits at the flange).
ARM_WIDE = ("payload",)
# Friction dissipates: a fit that feeds energy in is not friction but evidence of something else, named here
# with the library families that could be it. Position-dependent terms (springs, periodic terms, offsets)
# may take either sign: counterbalance springs, gas struts, cable carriers and hoses act either way in the
# measured motor torque.
NOT_DISSIPATIVE = {
    "coulomb_friction": ("a torque that steps with the direction of motion and helps it: friction "
                         "compensation in the drive that over-compensates, a direction-dependent offset of "
                         "the torque signal, or direction memory",
                         ("backlash", "current_offset", "coupling")),
    "viscous_friction": ("a torque proportional to velocity that helps the motion: the torque signal lagging "
                         "the state (filtering, sampling phase), velocity feed-forward or back-EMF "
                         "compensation in the drive, or an inertia error", ("delay", "torque_constant_scale",
                                                                          "coupling")),
    "stribeck_friction": ("friction that grows away from standstill instead of falling: viscous friction, or "
                          "a lag of the torque signal", ("viscous_friction", "delay")),
}
PAYLOAD_MAX_DISTANCE_M = 1.0  # a centre of mass farther from the flange is not a payload "at the flange"
G = 9.81  # m/s^2

SIGN_EPS = 0.01  # rad/s: tanh(qd / SIGN_EPS) stands for sign(qd) without the jump at qd = 0


@dataclass
class Effect:
    family: str
    joint: int
    hyper: dict = field(default_factory=dict)
    coef: np.ndarray | None = None
    ref: np.ndarray | None = None  # frozen rigid-part parameters (torque_constant_scale, delay)
    in_kg: bool = True  # payload: False when its current scale has no reference (payload.py)

    @property
    def key(self) -> tuple:
        return (self.family, self.joint, tuple(sorted((k, round(v, 9) if isinstance(v, float) else v)
                                                      for k, v in self.hyper.items())))

    @property
    def wide(self) -> bool:
        """True for a family that acts on every joint (shared coefficients), e.g. a payload."""
        return self.family in ARM_WIDE

    def on_joint(self, feats: np.ndarray, j: int) -> np.ndarray | None:
        """This effect's columns (N, k) in joint j's equation, given its features(); None: not on joint j."""
        if self.wide:
            return feats[:, j, :]
        return feats if self.joint == j else None

    @property
    def slot(self) -> tuple:
        """Two effects with the same slot are the same thing: only one of them is kept in a model."""
        return (self.family, self.joint, self.hyper.get("other_joint"), self.hyper.get("source"))

    def features(self, d) -> np.ndarray:
        """(N, k) columns on a Design `d` (stacked segments, see greybox.Design); (N, n, k) for an arm-wide
        family."""
        if self.wide:
            return _FEATURES[self.family](self, d)
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
        if f == "payload":  # coefficients: mass [kg] and first moment m * c [kg*m] in the last link's frame
            m = c[0]
            com = [x / m if abs(m) > 1e-9 else float("nan") for x in c[1:4]]
            return {"mass_kg": m, "com_x_m": com[0], "com_y_m": com[1], "com_z_m": com[2],
                    "distance_m": float(np.linalg.norm(com))}
        if f == "gravity_load":
            return {"amplitude": float(np.sqrt(np.sum(np.square(c))))}
        return {"coef": c}

    def describe(self, units: str = "N*m", names=None) -> str:
        """The effect in words a user understands (one clause)."""
        p, j = self.params(), self.joint
        name = names[j] if names is not None and j < len(names) else f"joint {j}"
        if self.family == "payload":
            d = p["distance_m"]
            static = ("; its gravity only: the data show no inertia of it (a static load, e.g. a cable or "
                      "hose weight)") if self.hyper.get("dynamics") == "gravity" else ""
            mass = (f"about {p['mass_kg']:.2g} kg" if self.in_kg else
                    "its mass cannot be stated in kg (no reference for the current-per-torque scale),")
            return (f"an unknown payload: {mass} at {100 * d:.0f} cm from the flange "
                    f"(centre of mass {100 * p['com_x_m']:.1f}, {100 * p['com_y_m']:.1f}, "
                    f"{100 * p['com_z_m']:.1f} cm in the last link's frame{static})")
        if self.family == "gravity_load":
            return (f"a gravity-like load on {name} (a payload or a wrong mass; no arm description, so its "
                    "mass and position are not identified)")
        if self.family == "position_spring":
            return (f"a position spring on {name}: {p['stiffness_per_rad']:.3g} {units}/rad about "
                    f"{p['rest_position_rad']:.3g} rad")
        if self.family == "position_periodic":
            return (f"a position-periodic torque on {name}: {p['amplitude']:.3g} {units}, period "
                    f"{p['period_rad']:.4g} rad")
        shown = ", ".join(f"{k} {v:.3g}" for k, v in p.items() if isinstance(v, float))
        return f"{self.family.replace('_', ' ')} on {name}" + (f" ({shown})" if shown else "")

    def implausible(self) -> str:
        """Why the fitted parameters are physically impossible for this family ("" when they are not): a
        torque-constant scale outside 0.5-2, a negative / over-half-second delay, friction that feeds energy
        in (see NOT_DISSIPATIVE), a negative payload mass or one whose centre is over a metre from the
        flange. No sign is assumed for position-dependent terms: a spring of either stiffness is possible."""
        if self.coef is None:
            return ""
        p = self.params()
        if self.family == "torque_constant_scale" and not 0.5 <= p["scale"] <= 2.0:
            return f"scale {p['scale']:.3g} outside 0.5..2"
        if self.family == "delay" and not 0.0 <= p["delay_s"] <= 0.5:
            return f"delay {p['delay_s']:.3g} s outside 0..0.5 s"
        if self.family in NOT_DISSIPATIVE:
            key = {"coulomb_friction": "fc", "viscous_friction": "fv", "stribeck_friction": "fs_extra"}
            v = p[key[self.family]]
            if v < 0.0:
                name = self.family.replace("_", " ")
                return f"negative {name} {key[self.family]} {v:.3g}: friction dissipates"
        if self.family == "payload":
            if p["mass_kg"] <= 0.0:
                return f"payload mass {p['mass_kg']:.3g} kg is not positive"
            if not p["distance_m"] <= PAYLOAD_MAX_DISTANCE_M:
                return (f"payload centre {p['distance_m']:.3g} m from the flange "
                        f"(> {PAYLOAD_MAX_DISTANCE_M:g} m)")
        return ""

    def evidence_of(self) -> dict:
        """For friction fitted with the wrong sign: what it is evidence of, and the candidate families."""
        if self.family not in NOT_DISSIPATIVE or not self.implausible():
            return {}
        what, cands = NOT_DISSIPATIVE[self.family]
        return {"evidence_of": what, "candidates": list(cands)}

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
    "payload": lambda e, d: d.payload_columns(e.hyper.get("dynamics", "full")),
    "gravity_load": lambda e, d: _gravity_like(d.q),
}


def _gravity_like(q: np.ndarray) -> np.ndarray:
    from .basis import gravity_like  # the data-only basis' own gravity-like columns

    return gravity_like(q)


def _lagged(t: np.ndarray, x: np.ndarray, shift_s: float) -> np.ndarray:
    """x(t - shift) - x(t) on a possibly irregular clock (held at the first value before the start). A shift
    rather than a derivative: the rigid prediction carries M(q) qdd, and differentiating that noise would bias
    the fitted lag toward zero (errors in the regressor)."""
    return np.interp(t - shift_s, t, x) - x
