"""The rigid-body part of the grey-box model, linear in its parameters.

DataBasis (no arm description): for every joint the same set of functions of the state --
  gravity-like  sin/cos of every contiguous sum q_a + ... + q_b (a serial arm's link orientations),
  inertia-like  qdd_k for all k, and qdd_j * sin/cos(q_m) for the other joints m (configuration-dependent
                diagonal inertia),
  velocity products qd_k * qd_l (Coriolis/centripetal-like)
with separate coefficients per joint. Deliberately no constant, no sign(qd) and no qd: offsets and friction
are effects in the library, so the loop has to find them.

PinocchioBasis (an arm description): tau = Y(q, qd, qdd) theta with pinocchio's joint-torque regressor,
reduced to base parameters by QR with column pivoting on a stack of regressors at random states (the
identifiable combinations), shared by all joints. Physical consistency: the fit is regularised toward the
nominal base parameters of the description (ridge on theta - theta_nominal), so poorly excited combinations
stay at their nominal, physically consistent values instead of drifting to arbitrary ones.

A payload on the last link is a change of that link's inertial parameters: its columns (payload_columns) lie
in the span of the base regressor (measured on the UR5: residual 0 after projection). So the data alone cannot
tell a payload from an error of the description's last links; only the prior can. Pulled toward the CAD
description, every difference between the real wrist and its CAD values is reported as payload (the twin's
true body, +-15 % mass and +-1 cm centre of mass per link, put a 2 kg payload at -8 % and its position 16 %
off). `reference_prior` pulls toward the arm as identified on a run without the change instead (a
calibration run, fitted with the weak REFERENCE_RIDGE: a coverage trajectory excites every base parameter),
so what is found is the change since then.
"""

from __future__ import annotations

import numpy as np

from .data import Segment


def independent_columns(a: np.ndarray, rtol: float = 1e-8) -> np.ndarray:
    """Indices of a maximal set of linearly independent columns: QR with column pivoting (Businger-Golub),
    i.e. repeatedly take the column with the largest norm left after projecting out the ones taken."""
    r = np.array(a, float)
    norms = np.sum(r * r, 0)
    first = norms.max() if norms.size else 0.0
    chosen: list[int] = []
    for _ in range(min(r.shape)):
        k = int(np.argmax(norms))
        if norms[k] <= (rtol ** 2) * first or norms[k] <= 0:
            break
        v = r[:, k] / np.sqrt(norms[k])
        r -= np.outer(v, v @ r)
        norms = np.sum(r * r, 0)
        norms[chosen + [k]] = 0.0
        chosen.append(k)
    return np.sort(np.array(chosen, int))


def payload_columns(model, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """(N, n, 4) joint torques [N*m] per unit of a point payload's parameters on the last link: mass m [kg],
    first moment m*c [kg*m] (c: its centre in the last joint's frame [m]) -- pinocchio's joint-torque
    regressor columns of the last body's mass and first moment, so gravity, inertia and Coriolis of the mass
    all go through the arm's kinematics. Linear in (m, m*c); the payload's own rotational inertia (about
    m |c|^2, 1e-3 kg*m^2 for 0.3 kg at 5 cm) is left out."""
    import pinocchio as pin

    data = model.createData()
    k = 10 * (model.njoints - 2)  # dynamic parameters of the last joint's body: m, m*c (3), inertia (6)
    return np.stack([np.asarray(pin.computeJointTorqueRegressor(model, data, q[i], qd[i], qdd[i]))[:, k:k + 4]
                     for i in range(len(q))])


def gravity_like(q: np.ndarray) -> np.ndarray:
    """(N, n(n+1)) sin and cos of every contiguous joint-angle sum q_a + ... + q_b [rad]: the orientations a
    serial arm's links can have relative to gravity, so any load's gravity torque is close to a combination
    of them (the data-only basis' gravity part, and the gravity_load family without an arm description)."""
    n = q.shape[1]
    cq = np.cumsum(np.concatenate([np.zeros((len(q), 1)), q], 1), 1)
    ang = np.stack([cq[:, b + 1] - cq[:, a] for a in range(n) for b in range(a, n)], 1)
    return np.concatenate([np.sin(ang), np.cos(ang)], 1)


class DataBasis:
    kind = "data-only"
    separable = True  # each joint has its own coefficients: an effect on joint j changes only joint j's fit
    kinematics = None  # no arm description
    offers_gravity_load = False  # its own gravity-like columns span that family already

    def __init__(self, n: int):
        self.n = n
        self.sums = [(a, b) for a in range(n) for b in range(a, n)]
        self.pairs = [(k, m) for k in range(n) for m in range(k, n)]
        self.per_joint = 2 * len(self.sums) + n + 2 * (n - 1) + len(self.pairs)
        self.n_params = self.per_joint * n
        self.prior = np.zeros(self.n_params)
        # relative to the column energy, per parameter. The functions are strongly collinear over a short log:
        # too little ridge and the fit extrapolates wildly outside the visited joint ranges (UR5 held-out L1
        # x8 at 1e-6), too much and it is biased. select_ridge() picks it per joint by cross-validation.
        self.ridge = np.full(self.n_params, 1e-6)

    def describe(self) -> str:
        return (f"data-only basis: {self.per_joint} functions per joint (sin/cos of {len(self.sums)} "
                f"joint-angle sums, {self.n + 2 * (self.n - 1)} inertia-like, "
                f"{len(self.pairs)} velocity products)")

    def blocks(self, seg: Segment) -> list[tuple[np.ndarray, np.ndarray]]:
        grav = gravity_like(seg.q)
        vel = np.stack([seg.qd[:, k] * seg.qd[:, m] for k, m in self.pairs], 1)
        out = []
        for j in range(self.n):
            others = [m for m in range(self.n) if m != j]
            inert = [seg.qdd] + [seg.qdd[:, [j]] * f(seg.q[:, others]) for f in (np.sin, np.cos)]
            cols = np.concatenate([grav] + inert + [vel], 1)
            out.append((np.arange(j * self.per_joint, (j + 1) * self.per_joint), cols))
        return out


RIDGE_GRID = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2)


def select_ridge(basis: DataBasis, segments: list[Segment], grid=RIDGE_GRID, joints=None,
                 effects_of=None) -> dict:
    """Choose the data-only basis' ridge per joint by leave-one-out over contiguous folds of the training
    data (its runs, or 4 contiguous blocks of a single run): the value with the lowest mean absolute error
    on the left-out fold. `effects_of(segment)` -> (N, n) contribution of the effects already in the model,
    subtracted from the target first (their coefficients held at the current fit), so that the choice is made
    on what the rigid part has to explain. Sets basis.ridge; returns {joint: ridge}."""
    if len(segments) >= 2:
        folds = segments
    else:
        s = segments[0]
        cuts = np.linspace(0, len(s), 5).astype(int)
        folds = [s.slice(a, b, f"{s.name}[{k}]") for k, (a, b) in enumerate(zip(cuts[:-1], cuts[1:]))]
    blocks = [basis.blocks(f) for f in folds]
    ys = [f.tau - effects_of(f) if effects_of is not None else f.tau for f in folds]
    grams = [[(c.T @ c, c.T @ y[:, j]) for j, (_, c) in enumerate(b)] for b, y in zip(blocks, ys)]
    chosen = {}
    for j in range(basis.n) if joints is None else joints:
        g_all = sum(g[j][0] for g in grams)
        b_all = sum(g[j][1] for g in grams)
        err = []
        for lam in grid:
            e = 0.0
            for k in range(len(folds)):
                g = g_all - grams[k][j][0]
                theta = np.linalg.lstsq(g + lam * np.diag(np.maximum(np.diag(g), 1e-12)),
                                        b_all - grams[k][j][1], rcond=None)[0]
                e += np.sum(np.abs(ys[k][:, j] - blocks[k][j][1] @ theta))
            err.append(e)
        chosen[j] = float(grid[int(np.argmin(err))])
        idx = blocks[0][j][0]
        basis.ridge[idx] = chosen[j]
    return chosen


REFERENCE_RIDGE = 1e-3  # prior weight of a reference identification (UR5 twin: held-out L1 of the shoulder
# 0.022 N*m at 1e-3, 0.321 at the default 1.0, which holds the base parameters at the CAD description's)


def reference_prior(basis: PinocchioBasis, theta, columns) -> None:
    """Pull `basis` toward base parameters identified on a reference run (the arm before a change: a
    payload, a new tool) instead of the description's. theta: their values, columns: the base-regressor
    columns they belong to (ValueError when they are not this basis' columns: another arm or version)."""
    if list(columns) != [int(c) for c in basis.cols] or len(theta) != basis.n_params:
        raise ValueError(f"{len(theta)} base parameters of columns {list(columns)[:4]}..., this arm has "
                         f"{basis.n_params} of columns {basis.cols.tolist()[:4]}...")
    basis.prior = np.asarray(theta, float).copy()


class PinocchioBasis:
    kind = "pinocchio"
    separable = False  # base parameters are shared by all joints
    offers_gravity_load = False  # a load is the payload family here (through the arm's kinematics)

    def __init__(self, model, seed: int = 0, ridge: float = 1e-3):
        import pinocchio as pin

        self.pin, self.model, self.data = pin, model, model.createData()
        self.kinematics = model  # the arm description behind the payload family
        self.n = model.nv
        if model.nq != model.nv:
            raise ValueError("only revolute/prismatic joints (nq == nv) are supported")
        nominal = np.concatenate([model.inertias[i].toDynamicParameters() for i in range(1, model.njoints)])
        rng = np.random.default_rng(seed)
        lo = np.where(np.isfinite(model.lowerPositionLimit), model.lowerPositionLimit, -np.pi)
        hi = np.where(np.isfinite(model.upperPositionLimit), model.upperPositionLimit, np.pi)
        n = self.n
        stack = np.concatenate([self._full(rng.uniform(lo, hi), rng.normal(size=n), rng.normal(size=n))
                                for _ in range(60)])
        self.cols = independent_columns(stack)
        rank = len(self.cols)
        # nominal base parameters: the base regressor reproduces the full regressor's torques
        self.prior = np.linalg.lstsq(stack[:, self.cols], stack @ nominal, rcond=None)[0]
        self.n_params = rank
        self.ridge = ridge

    def describe(self) -> str:
        return f"pinocchio joint-torque regressor reduced to {self.n_params} base parameters (QR pivoting)"

    def _full(self, q, v, a) -> np.ndarray:
        return np.array(self.pin.computeJointTorqueRegressor(self.model, self.data, q, v, a))

    def regressor(self, seg: Segment) -> np.ndarray:
        """(N, n, n_params) base regressor along the segment."""
        return np.stack([self._full(seg.q[i], seg.qd[i], seg.qdd[i])[:, self.cols] for i in range(len(seg))])

    def nominal_torque(self, seg: Segment) -> np.ndarray:
        return np.einsum("tjp,p->tj", self.regressor(seg), self.prior)

    def blocks(self, seg: Segment) -> list[tuple[np.ndarray, np.ndarray]]:
        y = self.regressor(seg)
        idx = np.arange(self.n_params)
        return [(idx, y[:, j, :]) for j in range(self.n)]
