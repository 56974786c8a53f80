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
        arm description (its `kinematics`); dynamics "gravity": of a static load (qd = qdd = 0). Logs in
        current: joint j's columns times the basis' `current_scale` [A per N*m] (payload.py: where it comes
        from decides whether the mass is in kg)."""
        key = ("payload", dynamics)
        if key not in self._cache:
            from .basis import payload_columns

            z = np.zeros_like(self.qd)
            moving = dynamics == "full"
            cols = payload_columns(self.basis.kinematics, self.q, self.qd if moving else z,
                                   self.qdd if moving else z)
            scale = getattr(self.basis, "current_scale", None)
            self._cache[key] = cols if scale is None else cols * np.asarray(scale, float)[None, :, None]
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

    def offsets(self, d: Design) -> np.ndarray:
        """Where each effect's coefficients start in the solution vector (rigid parameters first)."""
        sizes = [d.features(e).shape[-1] for e in self.effects]
        return self.basis.n_params + np.concatenate([[0], np.cumsum(sizes)]).astype(int)

    def normal_equations(self, d: Design, rows=None) -> tuple[np.ndarray, np.ndarray]:
        """(A^T A, A^T y) of the stacked rigid + effect columns over all joints' equations; rows: a subset
        of the design's samples (index array; a bootstrap of contiguous blocks sums these), None = all."""
        feats = [d.features(e) for e in self.effects]
        offs = self.offsets(d)
        p = int(offs[-1])
        h = np.zeros((p, p))
        g = np.zeros(p)
        for j, (idx, cols) in enumerate(d.base):
            y = d.y[:, j]
            if rows is None:
                gj, bj = d.gram[j]
            else:
                cols, y = cols[rows], y[rows]
                gj, bj = cols.T @ cols, cols.T @ y
            h[np.ix_(idx, idx)] += gj
            g[idx] += bj
            mine = [(k, f if rows is None else f[rows]) for k, e in enumerate(self.effects)
                    if (f := e.on_joint(feats[k], j)) is not None]
            for a, (k, fk) in enumerate(mine):
                sk = slice(offs[k], offs[k + 1])
                h[idx, sk] += cols.T @ fk
                h[sk, idx] += (cols.T @ fk).T
                g[sk] += fk.T @ y
                for k2, f2 in mine[a:]:
                    s2 = slice(offs[k2], offs[k2 + 1])
                    blk = fk.T @ f2
                    h[sk, s2] += blk
                    if k2 != k:
                        h[s2, sk] += blk.T
        return h, g

    def solve(self, h: np.ndarray, g: np.ndarray, diag: np.ndarray | None = None) -> np.ndarray:
        """The regularised least-squares solution of normal equations (h, g); diag: the column energies
        the ridge is relative to (default: h's own diagonal)."""
        p0, p = self.basis.n_params, len(g)
        diag = np.maximum(np.diag(h).copy() if diag is None else diag, 1e-12)
        lam = np.full(p, EFFECT_RIDGE)
        lam[:p0] = self.basis.ridge
        prior = np.zeros(p)
        prior[:p0] = self.basis.prior
        reg = lam * diag
        return np.linalg.lstsq(h + np.diag(reg), g + reg * prior, rcond=None)[0]

    def fit(self, d: Design) -> GreyBox:
        sol = self.solve(*self.normal_equations(d))
        offs = self.offsets(d)
        self.theta = sol[:self.basis.n_params]
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
