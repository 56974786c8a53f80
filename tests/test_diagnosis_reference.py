"""A payload is found against the arm as identified before it was mounted (basis.reference_prior), not against
the description: a payload's columns lie in the base regressor's span, so against a description whose wrist is
off (as every real unit's is) the difference is reported as payload. Synthetic (pinocchio's sample arm)."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.diagnosis.basis import REFERENCE_RIDGE, PinocchioBasis, payload_columns, reference_prior
from calibration.diagnosis.loop import diagnose
from calibration.diagnosis.synthetic import pinocchio_arm

MASS, COM = 0.5, [0.0, 0.0, 0.08]  # kg, m in the last joint's frame


@pytest.fixture(scope="module")
def arms():
    pin = pytest.importorskip("pinocchio")
    from hardware.sim.example_effects import with_payload

    described = pin.buildSampleModelManipulator()
    real = described.copy()
    for k, f in ((real.njoints - 1, 1.15), (real.njoints - 2, 0.85)):  # the real wrist: +15 % / -15 % mass,
        i = real.inertias[k]                                           # its centre 1 cm off
        real.inertias[k] = pin.Inertia(i.mass * f, i.lever + np.array([0.01, 0.0, 0.01]), i.inertia * f)
    return described, real, with_payload(real, MASS, COM, 1e-6)


def _runs(model, first_seed: int):
    return [pinocchio_arm(model, None, duration_s=15.0, seed=s, name=f"run{s}") for s in
            range(first_seed, first_seed + 3)]


def _payload(dg):
    e = next(e for e in dg.found() if e.family == "payload")
    p = e.params()
    return p["mass_kg"], np.array([p["com_x_m"], p["com_y_m"], p["com_z_m"]])


def test_payload_columns_lie_in_the_base_regressor_span(arms):
    described, _, _ = arms
    basis = PinocchioBasis(described)
    s = pinocchio_arm(described, None, duration_s=3.0, seed=0)
    y = basis.regressor(s).reshape(-1, basis.n_params)
    f = payload_columns(described, s.q, s.qd, s.qdd).reshape(-1, 4)
    left = f - y @ np.linalg.lstsq(y, f, rcond=None)[0]
    assert np.all(np.linalg.norm(left, axis=0) < 1e-8 * np.linalg.norm(f, axis=0))


def test_payload_against_the_reference_identification_not_the_description(arms):
    described, real, loaded = arms
    loaded_runs = _runs(loaded, 10)
    mass_desc, com_desc = _payload(diagnose(PinocchioBasis(described, ridge=1.0), loaded_runs[:2],
                                            loaded_runs[2:]))
    plain = _runs(real, 0)  # the same unit before the payload: its own base parameters, weak prior
    ref = diagnose(PinocchioBasis(described, ridge=REFERENCE_RIDGE), plain[:2], plain[2:])
    assert ref.found() == []
    basis = PinocchioBasis(described, ridge=1.0)
    reference_prior(basis, ref.model.theta, ref.model.basis.cols)
    mass, com = _payload(diagnose(basis, loaded_runs[:2], loaded_runs[2:]))
    err_desc = max(abs(mass_desc / MASS - 1), np.linalg.norm(com_desc - COM) / np.linalg.norm(COM))
    err = max(abs(mass / MASS - 1), np.linalg.norm(com - COM) / np.linalg.norm(COM))
    assert err < 0.03 and err_desc > 3 * err, (err, err_desc)


def test_reference_of_another_arm_is_refused(arms):
    described, _, _ = arms
    basis = PinocchioBasis(described)
    with pytest.raises(ValueError, match="base parameters"):
        reference_prior(basis, np.zeros(basis.n_params - 1), basis.cols[:-1])
