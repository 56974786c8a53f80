"""Which candidate the diagnose loop tries first (pure arrays, no arm, no fit): with comparable held-out gains
(an arm description, NEXT) the effect that explains the most torque in absolute units leads, even when a
single-joint effect explains a larger fraction of a small joint's residual (issue 25: the twin's wrist
friction was reported before an undeclared payload that explained more N*m on three joints)."""

from __future__ import annotations

import numpy as np

from calibration.diagnosis.effects import Effect
from calibration.diagnosis.loop import proposals
from calibration.diagnosis.trace import rank, shared, shared_fit, single_joint

N = 3000


def _arm_and_wrist(seed: int = 0):
    """Residual of 3 joints: a load with shared coefficients on joints 0-1 (0.4 N*m RMS each, 0.3 N*m of
    noise: about 64 % of each explained) and a 0.03 N*m friction step on the small joint 2 (0.003 N*m noise:
    about 99 % explained)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 30, N)
    q = np.stack([np.sin(0.7 * t), np.sin(0.4 * t + 1), np.sin(1.3 * t)], 1)
    qd = np.gradient(q, t, axis=0)
    load = np.zeros((N, 3, 2))  # (N, joints, columns): a gravity-like load acting on joints 0 and 1
    load[:, 0] = np.stack([np.cos(q[:, 0]), np.cos(q[:, 0] + q[:, 1])], 1)
    load[:, 1] = np.stack([np.zeros(N), np.cos(q[:, 0] + q[:, 1])], 1)
    coef = np.array([0.3, 0.4])
    tau = np.einsum("tjk,k->tj", load, coef)
    tau[:, :2] *= 0.4 / np.sqrt(np.mean(tau[:, :2] ** 2, 0))
    tau[:, :2] += rng.normal(0, 0.3, (N, 2))
    friction = np.tanh(qd[:, 2] / 0.01)
    tau[:, 2] = 0.03 * friction + rng.normal(0, 0.003, N)
    return load, friction[:, None], tau


def test_shared_fit_explains_the_summed_residual():
    load, _, r = _arm_and_wrist()
    fit = shared_fit([load[:, j] for j in range(3)], [r[:, j] for j in range(3)])
    assert np.isclose(fit["residual_ss"], np.sum(r ** 2))
    assert 0.3 * fit["residual_ss"] < fit["explained_ss"] < fit["residual_ss"]
    assert all(0.5 < x < 0.8 for x in fit["per_joint"][:2])


def test_the_effect_explaining_more_torque_is_tried_first():
    load, friction, r = _arm_and_wrist()
    wide = shared(Effect("payload", 2, {"dynamics": "gravity"}), {j: load[:, j] for j in range(3)}, r)
    wrist = single_joint(Effect("coulomb_friction", 2), friction, r[:, 2])
    cands = sorted([wrist, wide], key=rank)
    # by fraction of its own joint's residual the wrist's friction leads (99 % vs ~65 %) ...
    assert cands[0] is wrist and wrist.score > 0.95 > 0.8 > wide.score > 0.5
    # ... but the load removes about 18 times more torque (N*m, summed over the joints it acts on)
    assert wide.explained > 5 * wrist.explained
    order, near = proposals(cands, close=0.5, by_units=True)
    assert order == [wide, wrist] and near(wide) and near(wrist)
    # without comparable held-out gains (data-only basis): the fraction order, first that passes is kept
    order, near = proposals(cands, close=np.inf, by_units=False)
    assert order == [wrist, wide] and not near(wide)


def test_proposals_alternate_so_small_joints_are_still_tried():
    """Four candidates on big joints explain more torque than the wrist's structure; the wrist's is still the
    second one tried (a round has 4 trial fits: by torque alone a structured small joint would wait behind
    every big joint's unexplainable residual)."""
    load, friction, r = _arm_and_wrist()
    big = [single_joint(Effect(f, j), load[:, j, :1] + 0.5 * k, r[:, j])
           for k, (f, j) in enumerate([("current_offset", 0), ("drift", 0), ("current_offset", 1)])]
    wrist = single_joint(Effect("coulomb_friction", 2), friction, r[:, 2])
    cands = sorted(big + [wrist], key=rank)
    order, _ = proposals(cands, close=0.5, by_units=True)
    assert order[1] is wrist and order[0] is max(big, key=lambda c: c.explained)
    assert len(order) == len(cands) and len({id(c) for c in order}) == len(cands)
