"""Trace a residual to an effect: every candidate effect on every joint is scored by the fraction of that
joint's training residual its features explain after projecting out what the current model can already
represent (rigid part + effects on that joint), and by the torque it explains in absolute units (`explained`:
RMS over samples of the residual it removes, summed in quadrature over the joints it acts on). Nonlinear
settings are searched here: the period of position_periodic from the periodogram of the residual against
joint position, the Stribeck velocity and the backlash width over short grids, the other joint of a coupling
over all joints.

Two orders: `rank` (the fraction of the joint's own residual: structure, whatever the joint's size -- a
wrist's friction is found although the shoulder's residual is ten times larger) and `rank_explained` (the
torque explained: an arm-wide payload that removes 0.4 N*m from three joints outranks a friction term that
removes 90 % of a 0.03 N*m wrist residual). The loop proposes from both and decides on held-out gain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.periodic import find_period

from .effects import Effect
from .greybox import Design, GreyBox

STRIBECK_VS = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)  # rad/s
DELAY_SHIFT = tuple(np.round(np.geomspace(0.004, 0.256, 13), 4))  # s: the lag is shift x fitted gain
BACKLASH_WIDTH = (0.002, 0.005, 0.01, 0.02, 0.05)  # rad
MOVING = 1e-3  # rad/s: a joint whose velocity RMS is below this did not move; no velocity-driven effects
PARSIMONY = 0.005  # ranking penalty per extra column: of two effects explaining the same, the simpler first


@dataclass
class Candidate:
    effect: Effect
    score: float  # fraction of the joint's training residual (sum of squares) explained
    evidence: dict
    # the training residual it explains in the data's units (N*m or A): sqrt(explained sum of squares / N),
    # summed over joints for an arm-wide effect; `residual` the same for the whole residual of those joints
    explained: float = 0.0
    residual: float = 0.0


class _Projector:
    """Removes from a feature what the current model's columns on joint j already span."""

    def __init__(self, model: GreyBox, d: Design, j: int, extra: list | None = None):
        idx, cols = d.base[j]
        mine = [f for e in model.effects if (f := e.on_joint(d.features(e), j)) is not None]
        # With parameters shared across joints (an arm description) joint j's own regressor row spans far
        # more than the shared fit can use on joint j alone, so only the effects are projected out there.
        own = [cols] if getattr(model.basis, "separable", False) else []
        self.m = np.concatenate(own + mine + list(extra or []) + [np.zeros((len(d), 0))], 1)
        if self.m.shape[1] == 0:
            self.m = np.zeros((len(d), 1))
        gram = self.m.T @ self.m
        self.gi = np.linalg.pinv(gram + 1e-9 * np.diag(np.maximum(np.diag(gram), 1e-12)))

    def __call__(self, f: np.ndarray) -> np.ndarray:
        return f - self.m @ (self.gi @ (self.m.T @ f))


def explained(f: np.ndarray, r: np.ndarray) -> float:
    rr = float(r @ r)
    if rr <= 0:
        return 0.0
    c, *_ = np.linalg.lstsq(f, r, rcond=None)
    return float(max(0.0, (r @ (f @ c)) / rr))


def candidates(model: GreyBox, d: Design, residual: np.ndarray, joints=None) -> list[Candidate]:
    """All candidate effects, best first."""
    taken = {e.slot for e in model.effects}
    out: list[Candidate] = []
    for j in range(model.n) if joints is None else joints:
        r = residual[:, j]
        if float(r @ r) <= 0:
            continue
        proj = _Projector(model, d, j)
        moving = float(np.sqrt(np.mean(d.qd[:, j] ** 2))) > MOVING

        def score(e: Effect, evidence: dict | None = None, proj=proj, r=r) -> Candidate:
            return single_joint(e, proj(d.features(e)), r, evidence)

        trials: list[Candidate] = [score(Effect("current_offset", j)),
                                   score(Effect("drift", j, {"source": "time"}))]
        if d.temp is not None and np.ptp(d.temp[:, j]) > 0.2:
            trials.append(score(Effect("drift", j, {"source": "temperature",
                                                    "temp_ref": float(np.mean(d.temp[:, j]))})))
        ref = model.theta.copy()
        if not getattr(model.basis, "separable", False):
            # with free per-joint coefficients (data-only basis) a scale of the rigid part is the rigid part:
            # not identifiable, and it would only undo the ridge's shrinkage
            trials.append(score(Effect("torque_constant_scale", j, ref=ref)))
        if moving:
            trials += [score(Effect("coulomb_friction", j)), score(Effect("viscous_friction", j)),
                       score(Effect("position_spring", j, {"q_ref": float(np.mean(d.q[:, j]))}))]
            trials.append(max((score(Effect("stribeck_friction", j, {"vs": v})) for v in STRIBECK_VS),
                              key=lambda c: c.score))
            trials.append(max((score(Effect("backlash", j, {"width_rad": w})) for w in BACKLASH_WIDTH),
                              key=lambda c: c.score))
            trials.append(max((score(Effect("delay", j, {"shift_s": float(s)}, ref=ref))
                               for s in DELAY_SHIFT), key=lambda c: c.score))
            found = find_period(d.q[:, j], r)
            if found is not None:
                period, frac, peak = found
                trials.append(score(Effect("position_periodic", j, {"period_rad": period}),
                                    {"periodogram_peak_over_median": round(peak, 2),
                                     "periodogram_explained": round(frac, 4)}))
        # another joint gets credit only for what joint j's own velocity cannot explain: in coordinated
        # motions qd_k correlates with qd_j, and a coupling would otherwise stand in for j's own friction
        own_motion = _Projector(model, d, j, [d.features(Effect("coulomb_friction", j)),
                                              d.features(Effect("viscous_friction", j))])
        for k in range(model.n):
            if k != j and float(np.sqrt(np.mean(d.qd[:, k] ** 2))) > MOVING:
                trials.append(score(Effect("coupling", j, {"other_joint": k}), proj=own_motion))
        if getattr(model.basis, "offers_gravity_load", False):
            # one load, whatever the orientation columns it needs: ranked as a 2-column family
            c = score(Effect("gravity_load", j))
            c.evidence["columns"] = 2
            trials.append(c)
        for c in trials:
            if c.effect.slot in taken:
                continue
            c.evidence["explains_train_residual"] = round(c.score, 4)
            c.evidence["explains_train_units"] = round(c.explained, 6)
            out.append(c)
    if getattr(model.basis, "kinematics", None) is not None:
        # a payload moves with the arm (its inertia shows); a static load (a cable's weight) only weighs
        for dyn in ("full", "gravity"):
            c = _arm_wide(model, d, residual, Effect("payload", model.n - 1, {"dynamics": dyn}))
            if c.effect.slot not in taken:
                out.append(c)
    out.sort(key=rank)
    return out


def _arm_wide(model: GreyBox, d: Design, residual: np.ndarray, e: Effect) -> Candidate:
    """Score an effect that acts on every joint with shared coefficients: its coefficients are fitted to the
    training residual of all joints together (each joint's columns projected as that joint's candidates
    are). score: the largest fraction of one joint's residual that fit explains (comparable with a
    single-joint candidate's score); explained: the torque it removes summed over joints (comparable with a
    single-joint candidate's `explained`, in the same units)."""
    f = d.features(e)
    js = [j for j in range(model.n) if float(residual[:, j] @ residual[:, j]) > 0]
    return shared(e, {j: _Projector(model, d, j)(f[:, j, :]) for j in js}, residual)


def single_joint(e: Effect, f: np.ndarray, r: np.ndarray, evidence: dict | None = None) -> Candidate:
    """A candidate on one joint from its (projected) columns f (N, k) and that joint's residual r (N,)."""
    frac = explained(f, r)
    return Candidate(e, frac, {**(evidence or {}), "columns": f.shape[1]},
                     *in_units(frac * float(r @ r), float(r @ r), len(r)))


def shared(e: Effect, fs: dict[int, np.ndarray], residual: np.ndarray) -> Candidate:
    """A candidate acting on the joints in fs with one shared coefficient vector: fs[j] (N, k) its
    (projected) columns in joint j's equation, residual (N, n)."""
    js = list(fs)
    fit = shared_fit([fs[j] for j in js], [residual[:, j] for j in js])
    per_joint = {j: round(x, 4) for j, x in zip(js, fit["per_joint"])}
    sc = max(per_joint.values(), default=0.0)
    ex, tot = in_units(fit["explained_ss"], fit["residual_ss"], len(residual))
    cols = next(iter(fs.values())).shape[1] if fs else 1
    return Candidate(e, sc, {"columns": cols, "explains_train_residual": round(sc, 4),
                             "explains_train_units": round(ex, 6), "explains_per_joint": per_joint,
                             "acts_on": "all joints"}, ex, tot)


def shared_fit(fs: list[np.ndarray], rs: list[np.ndarray]) -> dict:
    """Least squares of one coefficient vector shared by several joints' equations: fs[i] (N, k) the
    (projected) columns of joint i, rs[i] (N,) its residual. -> coef, per_joint (fraction of each joint's
    residual sum of squares explained, >= 0), explained_ss / residual_ss (sums of squares over all joints:
    what the shared fit removes, >= 0 since coef = 0 is one of the fits it chose from)."""
    if not fs:
        return {"coef": np.zeros(0), "per_joint": [], "explained_ss": 0.0, "residual_ss": 0.0}
    coef = np.linalg.lstsq(np.concatenate(fs), np.concatenate(rs), rcond=None)[0]
    left = [float(np.sum((r - f @ coef) ** 2)) for f, r in zip(fs, rs)]
    total = [float(r @ r) for r in rs]
    return {"coef": coef, "per_joint": [max(0.0, 1.0 - a / b) if b > 0 else 0.0 for a, b in zip(left, total)],
            "explained_ss": max(0.0, sum(total) - sum(left)), "residual_ss": sum(total)}


def in_units(explained_ss: float, residual_ss: float, n_samples: int) -> tuple[float, float]:
    """Sums of squares over samples (and joints) -> the data's units: sqrt(ss / N) (explained, residual)."""
    n = max(int(n_samples), 1)
    return float(np.sqrt(max(explained_ss, 0.0) / n)), float(np.sqrt(max(residual_ss, 0.0) / n))


def rank(c: Candidate) -> float:
    """Sort key, best first: the fraction of the joint's own residual explained, less PARSIMONY per extra
    column."""
    return -(c.score - PARSIMONY * (c.evidence.get("columns", 1) - 1))


def rank_explained(c: Candidate) -> float:
    """Sort key, best first: the residual explained in the data's units (sum of squares over the joints the
    effect acts on), less the same PARSIMONY per extra column, as a fraction of that residual."""
    extra = PARSIMONY * (c.evidence.get("columns", 1) - 1) * c.residual ** 2
    return -(c.explained ** 2 - extra)


def trace_feature(e: Effect, d: Design) -> tuple[str, np.ndarray]:
    """The signal the residual is plotted against as evidence for an effect (axis label, values)."""
    j = e.joint
    if e.family in ("payload", "gravity_load") and e.coef is not None:
        f = e.on_joint(d.features(e), j)
        return f"fitted {e.family.replace('_', ' ')} torque on joint {j}", f @ e.coef
    if e.family in ("position_periodic", "position_spring"):
        return f"q[{j}] [rad]", d.q[:, j]
    if e.family == "backlash":
        return f"play state of q[{j}] (-1 after moving down, +1 after moving up)", d.features(e)[:, 0]
    if e.family == "drift":
        return ("t [s]", d.t) if e.hyper["source"] == "time" else (f"temperature[{j}] [degC]", d.temp[:, j])
    if e.family == "current_offset":
        return "t [s]", d.t
    if e.family in ("torque_constant_scale", "delay"):
        label = "rigid-part prediction" + (f" {e.hyper['shift_s']} s ago minus now" if e.family == "delay"
                                           else "")
        return label, d.features(e)[:, 0]
    if e.family == "coupling":
        k = e.hyper["other_joint"]
        return f"qd[{k}] [rad/s]", d.qd[:, k]
    return f"qd[{j}] [rad/s]", d.qd[:, j]
