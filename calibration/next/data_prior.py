"""The data-only prior: a grey box for arms the app has no description of (no MJCF, or a torque signal in A).

Per joint j, tau_j ~ columns_j(q, q_dot, q_ddot) @ c_j with the diagnosis's data-only basis
(calibration.diagnosis.basis.DataBasis: sin/cos of every contiguous joint-angle sum for gravity, q_ddot and
q_ddot_j * sin/cos of the other joints for inertia, velocity products for Coriolis) plus what a drive adds:
a smooth and a sharp Coulomb sign (tanh(q_dot / v)), viscous q_dot and a constant offset -- the effects
docs/diagnosis_cases.md finds first on the real UR5. Fitted by ridge on the training split; the ridge is
chosen per joint from RIDGE_GRID by leave-one-fold-out over contiguous folds of it (neighbouring samples are
nearly identical, so only contiguous folds measure extrapolation, which is what a collinear basis gets
wrong). Linear in its columns, so the same filtering as the identified prior applies
(calibration.next.prior_base: midpoint backward-difference acceleration, fit through the fixed low-pass on
both sides, estimate through the adaptive one): prior_torque = tau - F(tau - columns @ c), in the log's units
(N*m or A: nothing here needs N*m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.diagnosis.basis import gravity_like
from calibration.next import prior_base as pb
from calibration.next.prior_base import FRICTION_VEL, SHARP_VEL, Lowpass, TorquePrior, midpoints

KIND = "data-only"
RIDGE_GRID = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)  # relative to each column's energy
CV_FOLDS = 4  # contiguous folds of the training data for choosing the ridge (fewer than 3 runs)
CV_MAX_FOLDS = 8  # at most this many leave-runs-out folds
FULL_MIN_FOLD_S = 60.0  # with fewer than 3 runs, the full basis is tried only on time folds this long [s]


def n_columns(n: int) -> int:
    """Columns per joint for an n-joint arm (columns())."""
    return n * (n + 1) + n + 2 * (n - 1) + n * (n + 1) // 2 + 4


def columns(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """(N, n, P) design rows: for every sample and joint j, the data-only basis of joint j
    (calibration.diagnosis.basis.DataBasis) then tanh(qd_j / FRICTION_VEL), tanh(qd_j / SHARP_VEL), qd_j, 1.
    q [rad], qd [rad/s], qdd [rad/s^2], each (N, n)."""
    q, qd, qdd = (np.atleast_2d(np.asarray(a, float)) for a in (q, qd, qdd))
    n_s, n = q.shape
    grav = gravity_like(q)
    iu = np.triu_indices(n)
    vel = qd[:, iu[0]] * qd[:, iu[1]]
    out = np.empty((n_s, n, n_columns(n)))
    shared = np.concatenate([grav, qdd], 1)
    k0 = shared.shape[1]
    out[:, :, :k0] = shared[:, None, :]
    sq, cq = np.sin(q), np.cos(q)
    for j in range(n):
        others = [m for m in range(n) if m != j]
        out[:, j, k0:k0 + n - 1] = qdd[:, [j]] * sq[:, others]
        out[:, j, k0 + n - 1:k0 + 2 * (n - 1)] = qdd[:, [j]] * cq[:, others]
    k1 = k0 + 2 * (n - 1)
    out[:, :, k1:k1 + vel.shape[1]] = vel[:, None, :]
    k2 = k1 + vel.shape[1]
    out[:, :, k2] = np.tanh(qd / FRICTION_VEL)
    out[:, :, k2 + 1] = np.tanh(qd / SHARP_VEL)
    out[:, :, k2 + 2] = qd
    out[:, :, k2 + 3] = 1.0
    return out


@dataclass
class DataPrior(TorquePrior):
    """coef (n, P) per joint; ridge (n,) the chosen relative ridge; filter constants as prior.Prior."""

    coef: np.ndarray
    ridge: np.ndarray
    q_range: np.ndarray | None = None  # (2, n) [rad] the training data's range: q is clipped into it
    qd_range: np.ndarray | None = None  # (2, n) [rad/s] likewise
    basis: list[str] | None = None  # per joint "full" or "small" (fit_data_prior's choice; for reports)
    kind: str = KIND
    arm: str = ""  # no description
    cutoff_hz: float = pb.ACCEL_CUTOFF_HZ
    order: int = pb.FILTER_ORDER
    est_min_hz: float = pb.EST_MIN_HZ
    est_beta: float = pb.EST_BETA
    est_deriv_hz: float = pb.EST_DERIV_HZ
    uses_temperature: bool = False

    def design(self, q, qd, qdd) -> np.ndarray:
        """columns() with q and qd clipped into the training range: outside it the basis (sin/cos of angle
        sums, velocity products; strongly collinear) extrapolates wildly (UR5, trained on one run: 3.0 A
        held-out L1 unclipped), so there the prior holds the value at the edge of what it saw."""
        if self.q_range is not None:
            q = np.clip(q, self.q_range[0], self.q_range[1])
            qd = np.clip(qd, self.qd_range[0], self.qd_range[1])
        return columns(q, qd, qdd)

    def stream(self, rate_hz: float | None = None) -> DataPriorStream:
        return DataPriorStream(self, rate_hz)

    def torque(self, t, q, qd, tau, temperature=None) -> np.ndarray:
        """TorquePrior.torque, the columns computed for the whole run at once (data_prior_torque)."""
        return data_prior_torque(self, t, q, qd, tau)

    def to_dict(self) -> dict:
        return {"kind": KIND, "version": 1, "coef": self.coef.tolist(), "ridge": self.ridge.tolist(),
                "basis": self.basis, "q_range": None if self.q_range is None else self.q_range.tolist(),
                "qd_range": None if self.qd_range is None else self.qd_range.tolist(),
                "cutoff_hz": self.cutoff_hz, "order": self.order, "est_min_hz": self.est_min_hz,
                "est_beta": self.est_beta, "est_deriv_hz": self.est_deriv_hz}

    @classmethod
    def from_dict(cls, d: dict, n_joints: int | None = None) -> DataPrior:
        if d.get("kind") != KIND or d.get("version") != 1:
            raise ValueError(f"data-only prior kind/version {d.get('kind')!r}/{d.get('version')!r}")
        coef = np.asarray(d["coef"], float)
        n = coef.shape[0] if coef.ndim == 2 else -1
        if coef.ndim != 2 or coef.shape[1] != n_columns(n) or (n_joints is not None and n != n_joints):
            raise ValueError(f"data-only prior coefficients of shape {coef.shape}")
        if not np.all(np.isfinite(coef)):
            raise ValueError("data-only prior has non-finite coefficients")
        rng = [None if d.get(k) is None else np.asarray(d[k], float).reshape(2, n)
               for k in ("q_range", "qd_range")]
        return cls(coef, np.asarray(d["ridge"], float), *rng, basis=d.get("basis"),
                   cutoff_hz=float(d["cutoff_hz"]),
                   order=int(d["order"]),
                   est_min_hz=float(d["est_min_hz"]), est_beta=float(d["est_beta"]),
                   est_deriv_hz=float(d["est_deriv_hz"]))


def _filtered(p: DataPrior, run, chunk: int = 4096):
    """Yield (LP(columns) (k, n, P), LP(tau_mid) (k, n)) in chunks over one run through the fit's fixed
    low-pass (linear: LP(columns) @ c = LP(columns @ c))."""
    t, q, qd, tau = (np.asarray(a, float) for a in run)
    qm, qdm, qdd, taum = midpoints(t, q, qd, tau)
    lp = Lowpass(p.cutoff_hz, p.order)
    dts = np.diff(t, prepend=t[0])
    for lo in range(0, len(t), chunk):
        hi = min(lo + chunk, len(t))
        both = np.concatenate([p.design(qm[lo:hi], qdm[lo:hi], qdd[lo:hi]), taum[lo:hi, :, None]], 2)
        for k in range(hi - lo):
            both[k] = lp(both[k], dts[lo + k])
        yield both[:, :, :-1], both[:, :, -1]


def small_columns(n: int) -> np.ndarray:
    """(n, P) bool: per joint, the low-order subset of columns() -- sin/cos of each joint angle alone, the
    joint's own acceleration and the drive terms (friction, offset): what a ridge on hand features sees."""
    p = n_columns(n)
    sums = [(a, b) for a in range(n) for b in range(a, n)]
    single = [k for k, (a, b) in enumerate(sums) if a == b]
    mask = np.zeros((n, p), bool)
    mask[:, single] = True
    mask[:, [len(sums) + k for k in single]] = True
    for j in range(n):
        mask[j, 2 * len(sums) + j] = True
    mask[:, p - 4:] = True
    return mask


def _folds(lengths: list[int]) -> list[np.ndarray]:
    """Fold index of every row of each run: leave-one-run-out when there are >= 3 runs (at most CV_MAX_FOLDS
    folds of consecutive runs), else CV_FOLDS contiguous folds of the concatenation (cut in time)."""
    if len(lengths) >= 3:
        k = min(len(lengths), CV_MAX_FOLDS)
        return [np.full(m, i * k // len(lengths)) for i, m in enumerate(lengths)]
    cuts = np.linspace(0, sum(lengths), CV_FOLDS + 1).astype(int)
    rows = np.searchsorted(cuts, np.arange(sum(lengths)), side="right") - 1
    return np.split(rows, np.cumsum(lengths)[:-1])


def fit_data_prior(runs: list[tuple], grid=RIDGE_GRID) -> DataPrior:
    """Fit on free-motion runs (t [s], q [rad], qd [rad/s], tau [N*m or A]). Per joint, the basis (all of
    columns(), or its small_columns() subset) and the ridge are chosen by cross-validation (squared error,
    _folds): the full basis is strongly collinear and extrapolates badly to joint configurations no run
    visited (UR5, trained without the run that reaches them: 0.46 A full vs 0.29 A for a ridge on hand
    features), so it is a candidate only where the cross-validation can tell: leave-runs-out over 3 or more
    runs, or time folds of at least FULL_MIN_FOLD_S (one 82 s UR5 run cut in 20 s folds chose it and
    scored 1.8 A on other runs; the small basis 0.51 A)."""
    runs = [r[:4] for r in runs if len(r[0]) >= 2]
    if not runs:
        raise ValueError("no data to fit the data-only prior on")
    n = np.asarray(runs[0][1]).shape[1]
    n_p = n_columns(n)
    folds = _folds([len(r[0]) for r in runs])
    n_f = int(max(f.max() for f in folds)) + 1
    gram = np.zeros((n_f, n, n_p, n_p))
    rhs = np.zeros((n_f, n, n_p))
    yy = np.zeros((n_f, n))
    q_all = np.concatenate([np.asarray(r[1], float) for r in runs])
    qd_all = np.concatenate([np.asarray(r[2], float) for r in runs])
    q_range, qd_range = np.stack([q_all.min(0), q_all.max(0)]), np.stack([qd_all.min(0), qd_all.max(0)])
    shell = DataPrior(np.zeros((n, n_p)), np.zeros(n), q_range, qd_range)
    for run, fold_of in zip(runs, folds):
        row = 0
        for a, y in _filtered(shell, run):
            fold = fold_of[row:row + len(a)]
            for f in np.unique(fold):
                m = fold == f
                gram[f] += np.einsum("tjp,tjq->jpq", a[m], a[m])
                rhs[f] += np.einsum("tjp,tj->jp", a[m], y[m])
                yy[f] += np.sum(y[m] ** 2, 0)
            row += len(a)
    coef, ridge = np.zeros((n, n_p)), np.zeros(n)
    small = small_columns(n)
    dt = np.median(np.diff(np.asarray(runs[0][0], float)))
    fold_s = [dt * sum(int(np.sum(f == k)) for f in folds) for k in range(n_f)]
    full_ok = len(runs) >= 3 or (n_f >= 3 and min(fold_s) >= FULL_MIN_FOLD_S)
    basis = []
    for j in range(n):
        best = (np.inf, None, None)
        for name, cols in (("full", np.ones(n_p, bool)), ("small", small[j]))[0 if full_ok else 1:]:
            ix = np.ix_(cols, cols)
            g_all, b_all = gram[:, j][:, ix[0], ix[1]].sum(0), rhs[:, j][:, cols].sum(0)
            for lam in grid:
                e = 0.0
                for f in range(n_f):
                    gf, bf = gram[f, j][ix], rhs[f, j][cols]
                    g, b = g_all - gf, b_all - bf
                    c = np.linalg.solve(g + np.diag(lam * np.maximum(np.diag(g), 1e-12)), b)
                    e += yy[f, j] - 2 * c @ bf + c @ gf @ c
                if e < best[0]:
                    best = (e, (name, cols, lam), None)
        name, cols, lam = best[1]
        ix = np.ix_(cols, cols)
        g_all, b_all = gram[:, j][:, ix[0], ix[1]].sum(0), rhs[:, j][:, cols].sum(0)
        coef[j, cols] = np.linalg.solve(g_all + np.diag(lam * np.maximum(np.diag(g_all), 1e-12)), b_all)
        ridge[j] = lam
        basis.append(name)
    if not np.all(np.isfinite(coef)):
        raise ValueError("the data-only prior's least squares gave non-finite parameters")
    return DataPrior(coef, ridge, q_range, qd_range, basis=basis)


class DataPriorStream:
    """The data-only prior one sample at a time (prior.PriorStream's interface): update(q, qd, tau) ->
    tau - F(tau_mid - columns @ coef); over a run it equals data_prior_torque to rounding."""

    missing_temperature = False

    def __init__(self, p: DataPrior, rate_hz: float | None = None):
        self.p = p
        self.dt = None if rate_hz is None else 1.0 / rate_hz
        self.reset()

    def reset(self) -> None:
        self._prev = None
        self._lp = Lowpass(self.p.est_min_hz, self.p.order, self.p.est_beta, self.p.est_deriv_hz)

    def update(self, q, qd, tau, temperature=None, dt: float | None = None) -> np.ndarray:
        dt = self.dt if dt is None else dt
        cur = np.asarray(q, float), np.asarray(qd, float), np.asarray(tau, float)
        prev, self._prev = self._prev, cur
        if prev is None:
            qm, qdm, qdd, taum = cur[0], cur[1], np.zeros_like(cur[1]), cur[2]
        else:
            qm, qdm, taum = (0.5 * (a + b) for a, b in zip(cur, prev))
            qdd = (cur[1] - prev[1]) / dt
        pred = np.einsum("jp,jp->j", self.p.design(qm[None], qdm[None], qdd[None])[0], self.p.coef)
        return cur[2] - self._lp(taum - pred, dt)


def data_prior_torque(p: DataPrior, t, q, qd, tau) -> np.ndarray:
    """The prior's part of the torque signal (N, n) for one run, filters started at its first sample; the
    columns computed for the whole run at once, the filter stepped as DataPriorStream does."""
    t, tau = np.asarray(t, float), np.asarray(tau, float)
    qm, qdm, qdd, taum = midpoints(t, q, qd, tau)
    r = taum - np.einsum("tjp,jp->tj", p.design(qm, qdm, qdd), p.coef)
    lp = Lowpass(p.est_min_hz, p.order, p.est_beta, p.est_deriv_hz)
    dts = np.diff(t, prepend=t[0])
    return tau - np.array([lp(r[k], dts[k]) for k in range(len(t))])
