"""Example undeclared effects for the twin's hook (`--twin-effect hardware.sim.example_effects:NAME`).

piper_payload: a 300 g payload 5 cm beyond the Piper's last link that the arm description does not know
(a tool, a camera, cables): its gravity torque J^T m g [N*m] per joint, inside the drives. SIMULATED: it
tests calibration when the description is wrong, as it is on a real arm (the paper's baselines use the
vendor URDF). It is a static load only (no inertia), so it looks like a description error in free motion.

piper_spring_j0: a position spring on joint index 0, -1.5 N*m/rad about 0.4 rad (a counterbalance spring or
gas strut acting "the wrong way" in measured motor torque; springs act either way). SIMULATED.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

PAYLOAD_KG = 0.3
PAYLOAD_OFFSET_M = np.array([0.0, 0.0, 0.05])  # in the last joint's frame
SPRING_J0_N_M_PER_RAD, SPRING_J0_REST_RAD = -1.5, 0.4


def with_payload(model, mass_kg: float, offset_m=PAYLOAD_OFFSET_M, inertia_kg_m2: float = 1e-5):
    """A copy of a pinocchio model with a point-like payload (mass [kg] at offset [m] in the last joint's
    frame, rotational inertia [kg*m^2] about its centre) added to the last link."""
    import pinocchio as pin

    out = model.copy()
    last = model.njoints - 1
    out.inertias[last] = model.inertias[last] + pin.Inertia(mass_kg, np.asarray(offset_m, float),
                                                            np.eye(3) * inertia_kg_m2)
    return out


@lru_cache(maxsize=1)
def _piper():
    import pinocchio as pin

    from hardware.arms import load_arm

    m = load_arm("piper").pinocchio_model()
    with_load = with_payload(m, PAYLOAD_KG)
    return pin, m, m.createData(), with_load, with_load.createData()


def piper_payload(t: float, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
    """Gravity torque [N*m] of the undeclared payload at joint positions q [rad] (t, q_dot unused)."""
    pin, m, d, ml, dl = _piper()
    q = np.asarray(q, float)
    return pin.computeGeneralizedGravity(ml, dl, q) - pin.computeGeneralizedGravity(m, d, q)


def piper_spring_j0(t: float, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
    """k (q0 - q_rest) [N*m] on joint index 0 only (k = -1.5 N*m/rad, q_rest = 0.4 rad)."""
    tau = np.zeros(len(q))
    tau[0] = SPRING_J0_N_M_PER_RAD * (float(q[0]) - SPRING_J0_REST_RAD)
    return tau
