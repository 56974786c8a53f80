"""The grey-box model: rigid-body part (basis.py) + declared effects (effects.py), all linear in their
coefficients, fitted together by regularised least squares on the normal equations.

    y_j(t) = B_j(x(t)) theta_rigid + sum_{effects e on joint j} F_e(x) c_e

Ridge: every coefficient is penalised relative to its column energy (lambda * diag(A^T A)); the rigid part
toward its prior (zero for the data-only basis, the nominal base parameters for an arm description), the
effects toward zero with a much smaller weight.
"""

from __future__ import annotations

import copy

import numpy as np

from .data import Segment
from .effects import Effect

EFFECT_RIDGE = 1e-9


class Design:
    """Segments stacked into one set of arrays, with the rigid-part columns computed once."""

    def __init__(self, basis, segments: list[Segment]):
        self.basis = basis
        self.segments = segments
        lens = [len(s) for s in segments]
        ends = np.cumsum(lens)
        self.bounds = list(zip(ends - np.array(lens), ends))
        self.t = np.concatenate([s.t for s in segments])
        self.q = np.concatenate([s.q for s in segments])
        self.qd = np.concatenate([s.qd for s in segments])
        self.qdd = np.concatenate([s.qdd for s in segments])
        self.y = np.concatenate([s.tau for s in segments])
        temps = [s.temperature for s in segments]
        self.temp = None if any(x is None for x in temps) else np.concatenate(temps)
        blocks = [basis.blocks(s) for s in segments]
        self.base = [(blocks[0][j][0], np.concatenate([b[j][1] for b in blocks])) for j in range(basis.n)]
        self.gram = [(c.T @ c, c.T @ self.y[:, j]) for j, (_, c) in enumerate(self.base)]
        self._cache: dict = {}

    def __len__(self) -> int:
        return len(self.t)

    def features(self, e: Effect) -> np.ndarray:
        key = (e.key, None if e.ref is None else id(e.ref))
        if key not in self._cache:
            self._cache[key] = e.features(self)
        return self._cache[key]

    def payload_columns(self, dynamics: str = "full") -> np.ndarray:
        """(N, n, 4) torque per unit payload mass and first moment (basis.payload_columns) on the basis'
        arm description (its `kinematics`); dynamics "gravity": of a static load (qd = qdd = 0)."""
        key = ("payload", dynamics)
        if key not in self._cache:
            from .basis import payload_columns

            z = np.zeros_like(self.qd)
            moving = dynamics == "full"
            self._cache[key] = payload_columns(self.basis.kinematics, self.q, self.qd if moving else z,
                                               self.qdd if moving else z)
        return self._cache[key]


class GreyBox:
    def __init__(self, basis, effects: list[Effect] | None = None):
        self.basis = basis
        self.n = basis.n
        self.effects: list[Effect] = list(effects or [])
        self.theta = basis.prior.copy()

    def with_effect(self, e: Effect) -> GreyBox:
        m = copy.copy(self)
        m.effects = [copy.copy(x) for x in self.effects] + [copy.copy(e)]
        m.theta = self.theta.copy()
        return m

    def fit(self, d: Design) -> GreyBox:
        p0 = self.basis.n_params
        feats = [d.features(e) for e in self.effects]
        sizes = [f.shape[-1] for f in feats]
        offs = p0 + np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        p = int(offs[-1])
        h = np.zeros((p, p))
        g = np.zeros(p)
        for j, (idx, cols) in enumerate(d.base):
            gj, bj = d.gram[j]
            h[np.ix_(idx, idx)] += gj
            g[idx] += bj
            mine = [(k, f) for k, e in enumerate(self.effects) if (f := e.on_joint(feats[k], j)) is not None]
            for a, (k, fk) in enumerate(mine):
                sk = slice(offs[k], offs[k + 1])
                h[idx, sk] += cols.T @ fk
                h[sk, idx] += (cols.T @ fk).T
                g[sk] += fk.T @ d.y[:, j]
                for k2, f2 in mine[a:]:
                    s2 = slice(offs[k2], offs[k2 + 1])
                    blk = fk.T @ f2
                    h[sk, s2] += blk
                    if k2 != k:
                        h[s2, sk] += blk.T
        diag = np.maximum(np.diag(h).copy(), 1e-12)
        lam = np.full(p, EFFECT_RIDGE)
        lam[:p0] = self.basis.ridge
        prior = np.zeros(p)
        prior[:p0] = self.basis.prior
        reg = lam * diag
        sol = np.linalg.lstsq(h + np.diag(reg), g + reg * prior, rcond=None)[0]
        self.theta = sol[:p0]
        for k, e in enumerate(self.effects):
            e.coef = sol[offs[k]:offs[k + 1]]
        return self

    def rigid(self, d: Design) -> np.ndarray:
        return np.stack([cols @ self.theta[idx] for idx, cols in d.base], 1)

    def predict(self, d: Design) -> np.ndarray:
        out = self.rigid(d)
        for e in self.effects:
            if e.wide:
                out += np.einsum("tjk,k->tj", d.features(e), e.coef)
            else:
                out[:, e.joint] += d.features(e) @ e.coef
        return out


def errors(y: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint mean absolute error and RMS error."""
    r = y - pred
    return np.mean(np.abs(r), 0), np.sqrt(np.mean(r * r, 0))
