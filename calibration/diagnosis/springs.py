"""How far a found spring's stiffness can be trusted: what it is confounded with, said in the report.

A position spring k (q_j - q_ref) + c on joint j is linear in q_j. Over the range a joint visits, its own
gravity torque a sin(q_j + ...) + b cos(q_j + ...) is close to linear too, so a spring and an error of the
description's gravity on that joint are nearly the same columns. Measured on the Piper twin (whose true body
differs from the description by +-15 % mass, +-1 cm centre of mass per link): a 2 N*m/rad spring on joint 1
came out 2.32 (+16 %) with the rigid part held to the description (`--prior-weight 1.0`, the CLI's default)
and 1.99 with the rigid part identified on the same data (1e-3); on joint 0, which gravity does not load,
both within 1 %. So each found spring is refitted with the rigid part free (basis.REFERENCE_RIDGE: a
coverage run excites every base parameter), and the report gives both values and how much of the spring's
column the joint's own gravity columns explain (R^2 over the visited range).
"""

from __future__ import annotations

import copy

import numpy as np

from .basis import REFERENCE_RIDGE, gravity_like

AGREE = 0.10  # a refit that moves the stiffness by more than this is reported as confounded


def gravity_r2(spring_col: np.ndarray, gravity_cols: np.ndarray) -> float:
    """Fraction of the (centred) spring column explained by a joint's gravity columns plus a constant."""
    x = spring_col - spring_col.mean()
    a = np.concatenate([gravity_cols, np.ones((len(x), 1))], 1)
    coef = np.linalg.lstsq(a, x, rcond=None)[0]
    r = x - a @ coef
    return float(1.0 - (r @ r) / max(float(x @ x), 1e-300))


def _gravity_columns(basis, d, j: int) -> np.ndarray:
    """Joint j's gravity columns: the description's regressor at rest (pinocchio basis), else the data-only
    basis' gravity-like functions."""
    if getattr(basis, "cols", None) is not None:
        z = np.zeros(basis.n)
        step = max(1, len(d.q) // 2000)  # R^2 of a smooth column: a subsample is enough
        rows = np.stack([basis._full(q, z, z)[j, basis.cols] for q in d.q[::step]])
        keep = np.ptp(rows, 0) > 1e-9
        return np.repeat(rows[:, keep], step, 0)[:len(d.q)]
    return gravity_like(d.q)


def spring_checks(dg) -> list[dict]:
    """For every position spring of the final model: its stiffness, the stiffness with the rigid part free
    (arm descriptions only), the gravity R^2 on its joint, and one sentence saying whether they agree."""
    springs = [(k, e) for k, e in enumerate(dg.model.effects) if e.family == "position_spring"]
    if not springs:
        return []
    basis, d = dg.model.basis, dg.train
    free = None
    held = np.ndim(basis.ridge) == 0 and basis.ridge > REFERENCE_RIDGE
    if getattr(basis, "cols", None) is not None and held:
        b = copy.copy(basis)
        b.ridge = REFERENCE_RIDGE
        free = copy.copy(dg.model)
        free.basis = b
        free.effects = [copy.copy(e) for e in dg.model.effects]
        from .greybox import Design

        free.fit(Design(b, d.segments))
    out = []
    for k, e in springs:
        j, stiff = e.joint, float(e.coef[0])
        r2 = gravity_r2(d.q[:, j], _gravity_columns(basis, d, j))
        row = {"joint": j, "stiffness_per_rad": stiff, "gravity_r2": round(r2, 4)}
        if free is not None:
            kf = float(free.effects[k].coef[0])
            row["stiffness_free_rigid_per_rad"] = kf
            moved = abs(kf / stiff - 1) if stiff else np.inf
            row["moved"] = round(float(moved), 4)
            if moved > AGREE:
                row["words"] = (f"stiffness confounded with gravity on joint {j}: over the visited range the "
                                f"joint's own gravity columns explain {100 * r2:.0f} % of the spring's, so "
                                f"an error of the description's masses there reads as stiffness -- "
                                f"{stiff:.4g} with the rigid part held to the description, {kf:.4g} with it "
                                "identified on these data (trust the second when the run covers the "
                                "workspace)")
            else:
                row["words"] = (f"stiffness {stiff:.4g} ({kf:.4g} with the rigid part identified on these "
                                f"data: within {100 * AGREE:.0f} %)")
        else:
            row["words"] = (f"stiffness {stiff:.4g}; the joint's own gravity columns explain "
                            f"{100 * r2:.0f} % of the spring's over the visited range" + (
                                ": an error of the model's gravity there would read as stiffness"
                                if r2 > 0.5 else ""))
        out.append(row)
    return out
