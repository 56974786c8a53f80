"""diagnose on simulated logs from a known model with one effect injected: it must name the effect's family
and joint, recover its parameters, and at least halve that joint's held-out error; with nothing injected it
must add nothing (simulated data: calibration.diagnosis.synthetic)."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.diagnosis.basis import DataBasis, PinocchioBasis
from calibration.diagnosis.loop import diagnose
from calibration.diagnosis.synthetic import analytic_arm, pinocchio_arm


def _runs(effect, joint, seconds=30.0, **params):
    return [analytic_arm(effect, joint, seconds, seed=s, name=f"run{s}", **params) for s in range(3)]


def _check(dg, family, joint, ratio=0.5):
    first = dg.steps[1].added if len(dg.steps) > 1 else None
    assert first is not None, "nothing was added"
    assert (first["effect"], first["joint"]) == (family, joint), [s.added for s in dg.steps[1:]]
    before, after = dg.steps[0].heldout_l1[joint], dg.steps[-1].heldout_l1[joint]
    assert after <= ratio * before, (before, after)
    return next(e for e in dg.model.effects if e.family == family and e.joint == joint)


@pytest.mark.parametrize("family,joint,params", [
    ("coulomb_friction", 1, {"fc": 0.8}),
    ("viscous_friction", 2, {"fv": 1.5}),
    ("stribeck_friction", 1, {"fs": 1.2, "vs": 0.05}),
    ("backlash", 0, {"offset": 0.8, "width_rad": 0.02}),
    ("position_spring", 2, {"stiffness": 2.0}),
    ("drift", 1, {"rate_per_min": 1.0}),
    ("current_offset", 0, {"offset": 0.7}),
    ("delay", 1, {"delay_s": 0.03}),
    ("coupling", 1, {"viscous": 1.5, "coulomb": 0.5, "other_joint": 2}),
])
def test_data_only_basis_names_the_injected_effect(family, joint, params):
    runs = _runs(family, joint, **params)
    dg = diagnose(DataBasis(3), runs[:2], runs[2:])
    e = _check(dg, family, joint)
    p = e.params()
    if family == "coulomb_friction":
        assert p["fc"] == pytest.approx(0.8, rel=0.05)
    if family == "delay":
        assert p["delay_s"] == pytest.approx(0.03, rel=0.1)
    if family == "coupling":
        assert p["other_joint"] == 2 and p["viscous"] == pytest.approx(1.5, rel=0.05)
    if family == "drift":
        assert p["rate_per_min"] == pytest.approx(1.0, rel=0.05)
    if family == "backlash":
        assert p["offset"] == pytest.approx(0.8, rel=0.1)


@pytest.mark.parametrize("period", [0.25, 0.09])
def test_position_periodic_period_found_within_5_percent(period):
    runs = _runs("position_periodic", 2, amplitude=0.5, period_rad=period)
    dg = diagnose(DataBasis(3), runs[:2], runs[2:])
    p = _check(dg, "position_periodic", 2).params()
    assert p["period_rad"] == pytest.approx(period, rel=0.05)
    assert p["amplitude"] == pytest.approx(0.5, rel=0.1)


def test_no_injected_effect_adds_nothing():
    runs = _runs(None, 0)
    dg = diagnose(DataBasis(3), runs[:2], runs[2:])
    assert dg.model.effects == [] and len(dg.steps) == 1
    # and the rigid part explains the held-out data to the noise level (0.05 N*m std -> L1 ~ 0.04)
    assert max(dg.steps[0].heldout_l1) < 0.05


def test_single_run_is_split_into_contiguous_blocks():
    from calibration.diagnosis.data import split_heldout

    run = analytic_arm("coulomb_friction", 1, 40.0, seed=3)
    train, held = split_heldout([[run]], None)
    assert train[0].t[-1] < held[0].t[0] + 1e-9 and len(held[0]) == len(run) - len(train[0])


def test_heldout_is_the_last_file_or_a_quarter_of_a_split_one():
    """A file whose contacts were cut out is many segments: all of the last file is held out, and a single
    such file holds out trailing segments worth at least a quarter of it (not just its last piece)."""
    from calibration.diagnosis.data import split_heldout

    run = analytic_arm("coulomb_friction", 1, 40.0, seed=3)
    step = len(run) // 10
    pieces = [run.slice(i, i + step, f"r#{k}") for k, i in enumerate(range(0, len(run), step))]
    pieces = [p for p in pieces if len(p)]
    train, held = split_heldout([pieces[:3], pieces[3:]], None)
    assert [p.name for p in held] == [p.name for p in pieces[3:]] and len(train) == 3
    train, held = split_heldout([pieces], None)
    n_held = sum(len(p) for p in held)
    assert n_held >= 0.25 * len(run) and len(train) + len(held) == len(pieces) and held[-1] is pieces[-1]
    dg = diagnose(DataBasis(3), train, held)
    _check(dg, "coulomb_friction", 1)


@pytest.fixture(scope="module")
def sample_arm():
    pin = pytest.importorskip("pinocchio")
    model = pin.buildSampleModelManipulator()
    return model, PinocchioBasis(model, ridge=1.0)


@pytest.mark.parametrize("family,joint", [("torque_constant_scale", 1), ("position_periodic", 3),
                                          ("current_offset", 2), (None, 0)])
def test_pinocchio_regressor_basis(sample_arm, family, joint):
    model, basis = sample_arm
    runs = [pinocchio_arm(model, family, joint, 15.0, seed=s, name=f"run{s}") for s in range(3)]
    dg = diagnose(basis, runs[:2], runs[2:])
    if family is None:
        assert dg.model.effects == []
        return
    # with parameters shared by all joints a scale error first leaks into the other joints; the backward
    # pruning pass must leave exactly the injected effect
    assert [(e.family, e.joint) for e in dg.model.effects] == [(family, joint)]
    e = dg.model.effects[0]
    if family == "torque_constant_scale":
        assert e.params()["scale"] == pytest.approx(1.15, rel=0.02)
    elif family == "current_offset":  # not a spring: its slope does not earn the threshold (Occam)
        assert dg.steps[1].added["effect"] == "current_offset"
        assert e.params()["offset"] == pytest.approx(0.7, rel=0.1)
    else:
        assert e.params()["period_rad"] == pytest.approx(0.25, rel=0.05)
    before = dg.steps[0].heldout_l1[joint]
    from calibration.diagnosis.greybox import errors

    after = errors(dg.heldout.y, dg.model.predict(dg.heldout))[0][joint]
    assert after <= 0.5 * before


def test_base_parameter_reduction_is_exact(sample_arm):
    model, basis = sample_arm
    pin = pytest.importorskip("pinocchio")
    data = model.createData()
    rng = np.random.default_rng(5)
    q, v, a = rng.normal(size=(3, model.nv))
    full = np.array(pin.computeJointTorqueRegressor(model, data, q, v, a))[:, basis.cols] @ basis.prior
    assert np.allclose(full, pin.rnea(model, data, q, v, a), atol=1e-8)


def test_final_model_holds_the_fit_of_its_own_effects():
    """The backward pass fits trial models without each effect; those fits must not overwrite the kept
    model's coefficients (they did once: the trial shared the effect objects)."""
    import copy

    from calibration.diagnosis.effects import Effect
    from calibration.diagnosis.greybox import GreyBox

    runs = _runs("coulomb_friction", 1, fc=0.8)
    for r in runs:  # a second effect on the same joint, declared up front
        r.tau[:, 1] += 1.5 * r.qd[:, 1]
    dg = diagnose(DataBasis(3), runs[:2], runs[2:], declared=[Effect("viscous_friction", 1)])
    kept = [(e.family, e.joint) for e in dg.model.effects]
    assert kept == [("viscous_friction", 1), ("coulomb_friction", 1)]
    refit = GreyBox(dg.model.basis, [copy.copy(e) for e in dg.model.effects]).fit(dg.train)
    for a, b in zip(dg.model.effects, refit.effects):
        assert np.allclose(a.coef, b.coef, rtol=1e-6, atol=1e-9), (a.family, a.coef, b.coef)


def test_cleaner_velocity_takes_the_smoother_signal():
    from calibration.diagnosis.data import cleaner_velocity

    rng = np.random.default_rng(0)
    t = np.arange(0, 20, 0.01)
    q = np.stack([np.sin(t), np.sin(0.5 * t)], 1)
    qd_true = np.stack([np.cos(t), 0.5 * np.cos(0.5 * t)], 1)
    noisy_qd = qd_true + 0.01 * rng.standard_normal(qd_true.shape)
    v, used = cleaner_velocity(t, q, noisy_qd)  # a fine encoder, a noisy speed estimate: differentiate q
    assert used.all() and np.abs(v - qd_true)[1:-1].max() < 1e-3
    noisy_q = q + 1e-3 * rng.standard_normal(q.shape)  # a coarse encoder, a clean speed: keep the speed
    v, used = cleaner_velocity(t, noisy_q, qd_true)
    assert not used.any() and np.array_equal(v, qd_true)


def test_segments_keep_the_logged_velocity_through_resampling():
    from calibration.diagnosis.data import make_segment, resample

    rng = np.random.default_rng(1)
    t = np.arange(0, 10, 0.008)
    q = np.stack([np.sin(t), np.cos(t)], 1)
    noisy_qd = np.stack([np.cos(t), -np.sin(t)], 1) + 0.01 * rng.standard_normal((len(t), 2))
    seg = make_segment("s", t, q, noisy_qd, np.zeros_like(q), "N*m")
    assert not np.array_equal(seg.qd, noisy_qd) and np.array_equal(seg.qd_logged, noisy_qd)
    r = resample(seg, 100.0)  # what a NEXT checkpoint is scored on: the velocity it was trained on
    ref = np.stack([np.interp(r.t, t, noisy_qd[:, j]) for j in range(2)], 1)
    np.testing.assert_allclose(r.qd_logged, ref)
    assert np.array_equal(seg.slice(5, 50, "c").qd_logged, noisy_qd[5:50])


def test_a_spring_takes_the_sign_the_data_supports():
    """Counterbalance springs, gas struts, cables act either way in motor torque: a negative stiffness is
    found, not rejected (it was, as 'implausible', before issue 25)."""
    dg = diagnose(DataBasis(3), *_split(_runs("position_spring", 2, stiffness=-2.0)))
    e = _check(dg, "position_spring", 2)
    assert e.params()["stiffness_per_rad"] == pytest.approx(-2.0, rel=0.1)
    assert e.params()["rest_position_rad"] == pytest.approx(0.2, abs=0.05)


def test_friction_that_feeds_energy_in_is_evidence_of_something_else():
    """A 'negative viscous friction' is never accepted as friction; its rejection names what it points at."""
    from calibration.diagnosis.effects import Effect

    e = Effect("viscous_friction", 1, coef=np.array([-0.4]))
    assert "friction dissipates" in e.implausible()
    assert "delay" in e.evidence_of()["candidates"] and "lag" in e.evidence_of()["evidence_of"]
    assert Effect("viscous_friction", 1, coef=np.array([0.4])).evidence_of() == {}
    assert Effect("position_spring", 1, {"q_ref": 0.0}, coef=np.array([-3.0, 0.1])).implausible() == ""
    dg = diagnose(DataBasis(3), *_split(_runs("viscous_friction", 1, fv=-1.5)))
    assert not any(x.family == "viscous_friction" and x.joint == 1 for x in dg.model.effects)
    bad = [r for r in dg.rejected if r["effect"] == "viscous_friction" and r["joint"] == 1]
    assert bad and "evidence_of" in bad[0] and "delay" in bad[0]["candidates"]


def test_payload_at_the_flange_is_found_with_its_mass_and_centre(sample_arm):
    """An arm carrying a load its description does not know (0.5 kg, 5 cm off the flange): the point-mass
    family through the arm's kinematics is found first and only, mass and centre recovered."""
    from calibration.diagnosis.report import headline
    from hardware.sim.example_effects import with_payload

    model, basis = sample_arm
    loaded = with_payload(model, 0.5, [0.03, 0.0, 0.04])
    runs = [pinocchio_arm(loaded, None, duration_s=15.0, seed=s, name=f"run{s}") for s in range(3)]
    dg = diagnose(basis, runs[:2], runs[2:])
    assert [(e.family, e.wide, e.hyper["dynamics"]) for e in dg.found()] == [("payload", True, "full")]
    p = dg.model.effects[0].params()
    assert p["mass_kg"] == pytest.approx(0.5, rel=0.05) and p["distance_m"] == pytest.approx(0.05, abs=0.005)
    assert np.mean(dg.steps[-1].heldout_l1) <= 0.5 * np.mean(dg.steps[0].heldout_l1)
    line = headline(dg, [f"j{k}" for k in range(6)], {"units": "N*m"})
    assert line.startswith("An unknown payload: about 0.5 kg at 5 cm from the flange"), line


def test_new_load_on_a_fixed_model_is_traced_to_gravity_without_a_description():
    """A predictor that knows the arm without the load (a stand-in for NEXT trained before a tool was
    mounted) and no arm description: the residual is a gravity-like load of the link orientations."""
    from calibration.diagnosis.next_loop import NextBasis
    from calibration.diagnosis.synthetic import LENGTH, G, analytic_torque

    runs = _runs(None, 0, seconds=20.0)
    for r in runs:  # 0.4 kg at the end of the planar arm
        ang = np.cumsum(r.q, 1)
        r.tau = r.tau + np.stack([0.4 * G * sum(LENGTH[m] * np.cos(ang[:, m]) for m in range(j, 3))
                                  for j in range(3)], 1)
    preds = {id(r): analytic_torque(r.q, r.qdd) for r in runs}
    dg = diagnose(NextBasis(3, preds, "stand-in predictor"), runs[:2], runs[2:])
    assert dg.steps[1].added["effect"] == "gravity_load"
    assert np.mean(dg.steps[-1].heldout_l1) <= 0.5 * np.mean(dg.steps[0].heldout_l1)


def _split(runs):
    return runs[:2], runs[2:]
