"""An unknown payload in physical units: which reference sets its scale, its interval, and what it says.

The payload family (effects.py) fits m [kg] and m*c [kg*m] through the arm's joint-torque regressor
(basis.payload_columns). In logs of motor current joint j's columns are multiplied by a current-per-torque
scale s_j [A per N*m] (greybox.Design.payload_columns, the basis' `current_scale`). Where s comes from
decides what the fitted m means:

- "torque": logs in N*m, no scale: m in kg.
- "torque constants": s = 1 / k_t from the vendor (`--kt`): m in kg.
- "description masses": s fitted by the identified-current prior (calibration/next/scaled_prior.py), whose
  free common factor is pinned by the description's masses: m in kg, as right as the CAD total.
- "known mass": s of the prior times alpha, alpha = m_found / m_known on a reference run with a payload of
  known mass (`--known-mass KG`): m in kg, as right as that mass.
- "none": per-joint ratios without a reference for their common factor (s_j / s_k are identifiable, the
  common factor is not: docs/arms_import.md): m is m_kg times an unknown factor and "cannot be stated in kg";
  the centre of mass c = (m c) / m does not depend on that factor and is stated in m.

Interval: a moving-block bootstrap of the final fit (`bootstrap`): the training samples cut into contiguous
blocks (a residual is correlated over seconds, so a white-noise covariance would be far too narrow), blocks
drawn with replacement, the normal equations summed and solved again; 2.5-97.5 % percentiles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REFERENCES = {
    "torque": "logs in N*m",
    "torque constants": "the vendor's torque constants (--kt)",
    "description masses": "the current-per-torque scales the identified-current prior fitted, referenced to "
                          "the arm description's masses",
    "known mass": "a reference run with a payload of known mass (--known-mass)",
    "none": "no reference for the common current-per-torque factor",
}
IN_KG = ("torque", "torque constants", "description masses", "known mass")


@dataclass
class CurrentScale:
    """scale: (n,) A per N*m multiplying the payload columns (None: logs in N*m); reference: a key of
    REFERENCES; detail: where it came from, in words."""

    scale: np.ndarray | None
    reference: str
    detail: str = ""

    @property
    def in_kg(self) -> bool:
        return self.reference in IN_KG

    def to_json(self) -> dict:
        return {"reference": self.reference, "meaning": REFERENCES[self.reference], "detail": self.detail,
                "in_kg": self.in_kg,
                "current_per_torque": None if self.scale is None else np.asarray(self.scale).tolist()}


UNIDENTIFIED = 0.25  # a fitted scale under this fraction of the joints' median (or <= 0) is not identified


def identified(scale) -> np.ndarray:
    """(n,) bool: which of the identified-current prior's scales are identified. A joint whose current
    carries almost no rigid-body torque (a wrist roll) gets a scale that friction absorbs at any value --
    on the real UR5 wrist 2 0.008 and wrist 3 -0.072 A per N*m against the controller's 0.09 / 0.12
    (docs/arms_import.md) -- and its payload columns would be scaled by that: such joints are left out of the
    payload's fit (columns zero) and named."""
    s = np.asarray(scale, float)
    pos = s[s > 0]
    return (s > 0) & (s >= UNIDENTIFIED * (np.median(pos) if len(pos) else np.inf))


def choose_scale(units: str, kt=None, prior_scale=None, known_alpha: float | None = None,
                 referenced: bool = True) -> CurrentScale | None:
    """The scale of the payload columns and its reference. units: of the logs; kt: vendor torque constants
    [N*m per A] per joint; prior_scale: the identified-current prior's scales [A per N*m]; known_alpha:
    m_found / m_known of a reference run (with prior_scale); referenced: whether the prior's common factor
    counts as referenced to the description's masses. None: no scale at all (the payload family cannot go
    through the kinematics in current; a gravity-like load is offered instead)."""
    if units == "N*m":
        return CurrentScale(None, "torque")
    if kt is not None:
        return CurrentScale(1.0 / np.asarray(kt, float), "torque constants")
    if prior_scale is None:
        return None
    ok = identified(prior_scale)
    s = np.where(ok, np.asarray(prior_scale, float), 0.0)
    left = ("" if ok.all() else "joints " + ", ".join(str(j) for j in np.flatnonzero(~ok))
            + " left out of the payload's fit (their scale is not identified)")
    if known_alpha is not None:
        what = f"alpha {known_alpha:.4g} on the prior's scales"
        return CurrentScale(s * known_alpha, "known mass", "; ".join(x for x in (what, left) if x))
    return CurrentScale(s, "description masses" if referenced else "none", left)


def alpha_from_known_mass(m_found: float, m_known_kg: float) -> float:
    """The common factor of the prior's scales from a reference run: the payload fitted with the prior's
    scales reads m_found = alpha * m_known (scale * alpha is the true one)."""
    if not (m_known_kg > 0 and np.isfinite(m_found) and m_found > 0):
        raise ValueError(f"a known mass needs a positive fitted mass on its run (found {m_found:.4g}, known "
                         f"{m_known_kg:.4g} kg)")
    return float(m_found / m_known_kg)


def fit_payload(residual: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Least squares of (m, m c) on all joints' residual together: residual (N, n), cols (N, n, 4)."""
    a = cols.transpose(1, 0, 2).reshape(-1, cols.shape[-1])
    return np.linalg.lstsq(a, residual.T.reshape(-1), rcond=None)[0]


def block_rows(bounds, block_s: float, t: np.ndarray) -> list[np.ndarray]:
    """Contiguous blocks of about block_s seconds inside each segment [lo, hi) of a design."""
    out = []
    for lo, hi in bounds:
        edges = [lo]
        t0 = t[lo]
        for i in range(lo + 1, hi):
            if t[i] - t0 >= block_s:
                edges.append(i)
                t0 = t[i]
        edges.append(hi)
        out += [np.arange(a, b) for a, b in zip(edges[:-1], edges[1:]) if b - a > 0]
    return out


def bootstrap(model, d, effect_index: int, n_boot: int = 200, block_s: float = 5.0, seed: int = 0
              ) -> np.ndarray:
    """(n_boot, k) coefficients of model.effects[effect_index] refitted on moving-block bootstrap draws of
    the design d's samples (the ridge relative to the full data's column energies, as in the fit)."""
    blocks = block_rows(d.bounds, block_s, d.t)
    eqs = [model.normal_equations(d, rows) for rows in blocks]
    h_all = sum(h for h, _ in eqs)
    diag = np.diag(h_all).copy()
    offs = model.offsets(d)
    sl = slice(int(offs[effect_index]), int(offs[effect_index + 1]))
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_boot):
        w = np.bincount(rng.integers(0, len(blocks), len(blocks)), minlength=len(blocks))
        h = sum(k * eqs[i][0] for i, k in enumerate(w) if k)
        g = sum(k * eqs[i][1] for i, k in enumerate(w) if k)
        out.append(model.solve(h, g, diag)[sl])
    return np.array(out)


def payload_params(coef) -> dict:
    """mass (in the fit's units: kg when referenced), centre of mass [m] and its distance from the flange."""
    m = float(coef[0])
    com = np.asarray(coef[1:4], float) / m if abs(m) > 1e-12 else np.full(3, np.nan)
    return {"mass": m, "com_m": com.tolist(), "distance_m": float(np.linalg.norm(com))}


def interval(samples: np.ndarray, level: float = 0.95) -> dict:
    """Percentile intervals of mass, centre of mass and distance over bootstrap coefficient samples."""
    p = [payload_params(c) for c in samples]
    lo, hi = 50 * (1 - level), 50 * (1 + level)

    def pct(x):
        x = np.asarray(x, float)
        x = x[np.isfinite(x)]
        return [float(np.percentile(x, lo)), float(np.percentile(x, hi))] if len(x) else [np.nan, np.nan]

    return {"level": level, "mass": pct([x["mass"] for x in p]),
            "com_m": [pct([x["com_m"][k] for x in p]) for k in range(3)],
            "distance_m": pct([x["distance_m"] for x in p])}


def summary(coef, samples: np.ndarray | None, scale: CurrentScale) -> dict:
    """report.json's `payload`: the reference, mass and centre of mass with their interval, in words."""
    p = payload_params(coef)
    out = {**scale.to_json(), **p}
    iv = interval(samples) if samples is not None and len(samples) else None
    if iv is not None:
        out["interval"] = iv
    c = p["com_m"]
    com = (f"centre of mass {100 * c[0]:.1f}, {100 * c[1]:.1f}, {100 * c[2]:.1f} cm in the last link's "
           f"frame, {100 * p['distance_m']:.1f} cm from the flange"
           + (f" ({100 * iv['distance_m'][0]:.1f}-{100 * iv['distance_m'][1]:.1f} cm)" if iv else ""))
    if scale.in_kg:
        out["mass_kg"] = p["mass"]
        rng = f" ({iv['mass'][0]:.3g}-{iv['mass'][1]:.3g} kg, 95 %)" if iv else ""
        out["words"] = f"{p['mass']:.3g} kg{rng}, {com}; reference: {REFERENCES[scale.reference]}"
    else:
        out["mass_kg"] = None
        out["words"] = (f"the mass cannot be stated in kg ({REFERENCES[scale.reference]}; "
                        f"{p['mass']:.3g} in the units of the scales used, i.e. kg times their unknown "
                        f"common factor); {com} (the centre does not depend on that factor)")
    return out
