"""The twin's true body (SIMULATED): each twin arm differs from its published description as configured, the
app-facing description never changes, and the twin's physics and ground truth run on the true body."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from hardware.arms import load_arm
from hardware.arms.true_body import (
    DESCRIPTION_ERRORS,
    BodyErrorMagnitudes,
    combine_point_masses,
    description_errors,
    gravity_torque,
    triangle_inertia,
    true_body,
)
from hardware.errors import ConfigError
from hardware.rigs import load_rig
from hardware.sim.actuators import Effects
from hardware.sim.twin import Twin

POSE = np.array([0.3, 1.0, -0.8, 0.2, 0.5, -0.3])


def _masses(model, arm):
    return np.array([model.body_mass[model.jnt_bodyid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)]]
                     for j in arm.joint_names])


@pytest.mark.parametrize("name", sorted(DESCRIPTION_ERRORS))
def test_true_body_is_drawn_within_its_magnitudes_and_leaves_the_description_alone(name):
    arm = load_arm(name)
    desc = arm.mujoco_model()
    before = (desc.body_mass.copy(), desc.body_ipos.copy(), desc.dof_armature.copy())
    mags = description_errors(name, arm.role)
    model, err = true_body(desc, arm, seed=3, mags=mags)
    for a, b in zip(before, (desc.body_mass, desc.body_ipos, desc.dof_armature)):
        np.testing.assert_array_equal(a, b)  # pure: the description's model is untouched
    ratio = err.mass_true / err.mass_desc
    horn_and_handle = err.horn_kg.max() + err.handle_kg
    assert np.all(ratio >= mags.mass_range[0] - 1e-9)
    assert np.all(err.mass_true - err.mass_desc * mags.mass_range[1] <= horn_and_handle + 1e-9)
    assert np.any(np.abs(ratio - 1) > 0.02)  # it really differs
    assert np.all(np.abs(err.com_shift) <= mags.com_m)
    for b in range(1, model.nbody):  # every body stays physical
        moments = np.sort(model.body_inertia[b])
        assert moments[0] + moments[1] >= moments[2] * (1 - 1e-9)
    dadr = arm.mujoco_indices(model)[1]
    fac = model.dof_armature[dadr] / desc.dof_armature[dadr]
    assert np.all(np.abs(fac - 1) <= mags.armature_frac + 1e-9) and np.any(np.abs(fac - 1) > 0.01)
    if arm.role == "leader":  # horns and the heavier handle: the leader needs more torque than described
        assert np.all(err.horn_kg >= mags.horn_kg[0]) and err.handle_kg >= mags.handle_kg[0] > 0
    # deterministic per seed, different across seeds
    again, _ = true_body(desc, arm, seed=3, mags=mags)
    np.testing.assert_array_equal(again.body_mass, model.body_mass)
    other, _ = true_body(desc, arm, seed=4, mags=mags)
    assert not np.allclose(other.body_mass, model.body_mass)


def test_zero_magnitudes_give_the_description_back():
    arm = load_arm("piper")
    zero = BodyErrorMagnitudes((1.0, 1.0), 0.0, 0.0, 0.0)
    model, _ = true_body(arm.mujoco_model(), arm, seed=0, mags=zero)
    np.testing.assert_allclose(model.body_mass, arm.mujoco_model().body_mass)
    np.testing.assert_allclose(gravity_torque(model, arm, POSE),
                               gravity_torque(arm.mujoco_model(), arm, POSE))


def test_rigid_body_arithmetic():
    # a point mass on the axis of a symmetric rod: mass adds, com moves, parallel-axis terms appear
    m, c, inertia = combine_point_masses(1.0, np.zeros(3), np.diag([0.1, 0.1, 0.0]), [(1.0, np.array([0, 0,
                                                                                                     2.0]))])
    assert m == 2.0 and np.allclose(c, [0, 0, 1.0])
    np.testing.assert_allclose(inertia, np.diag([0.1 + 2.0, 0.1 + 2.0, 0.0]))  # 1 kg at 1 m, twice
    np.testing.assert_allclose(triangle_inertia([1.0, 1.0, 5.0]), [1.0, 1.0, 2.0])


def _rig(error: bool):
    r = load_rig("sim-piper")
    off = {f.name: False for f in dataclasses.fields(Effects)}
    off["quantisation"] = True
    return dataclasses.replace(r, cameras=[], twin=dataclasses.replace(r.twin, effects=off,
                                                                       description_error=error))


def test_rig_key_parses_and_defaults_on(tmp_path):
    assert load_rig("sim-piper").twin.description_error is True
    text = (load_rig("sim-piper").path.read_text()
            .replace("[twin]\n", "[twin]\ndescription_error = false\n", 1))
    (tmp_path / "exact.toml").write_text(text)
    assert load_rig(tmp_path / "exact.toml").twin.description_error is False
    (tmp_path / "bad.toml").write_text(text.replace("description_error = false", "description_error = 1"))
    with pytest.raises(ConfigError, match="description_error"):
        load_rig(tmp_path / "bad.toml")


def test_twin_physics_and_ground_truth_run_on_the_true_body():
    arm = load_arm("piper")
    sha = arm.sha256
    twin = Twin(_rig(True), seed=0)
    exact = Twin(_rig(False), seed=0)
    try:
        # the unit is the rig's: another session seed changes the noise, not the body
        other = Twin(_rig(True), seed=7)
        np.testing.assert_array_equal(other.devices["follower"].body_error.mass_true,
                                      twin.devices["follower"].body_error.mass_true)
        other.close()
        fol, led = twin.devices["follower"], twin.devices["leader"]
        assert fol.body_error is not None and led.body_error is not None
        assert exact.devices["follower"].body_error is None
        # the twin's worlds hold the drawn true body; the exact twin and the app's description do not
        np.testing.assert_allclose(_masses(fol.world.model, arm), fol.body_error.mass_true)
        np.testing.assert_allclose(_masses(exact.devices["follower"].world.model, arm), _masses(
            arm.mujoco_model(), arm))
        assert np.abs(_masses(fol.world.model, arm) / _masses(arm.mujoco_model(), arm) - 1).max() > 0.02
        assert load_arm("piper").sha256 == sha  # the app-facing description never changes
        g_lead = gravity_torque(led.world.model, load_arm("gello_piper"), load_arm("gello_piper").q_home)
        g_lead_desc = gravity_torque(load_arm("gello_piper").mujoco_model(), load_arm("gello_piper"),
                                     load_arm("gello_piper").q_home)
        assert abs(g_lead[1]) > abs(g_lead_desc[1]) * 1.05  # horns + handle: a heavier leader than described

        # hold a pose: the reported torque is the TRUE body's gravity, not the description's, and the
        # ground truth's external torque stays zero (the model error is not an external torque)
        lsb = (fol.bank.p.current_lsb * fol.bank.p.kt)[:6]  # one firmware current unit [N*m]
        for tw in (twin, exact):
            d = tw.devices["follower"]
            d.world.set_qpos(d.bank, np.r_[POSE, 0.0][: d.bank.n])
            d.bank.enable(np.arange(d.bank.n), True)
            d.bank.command_position(np.arange(d.bank.n), np.r_[POSE, 0.0][: d.bank.n])
            d.world.ground_truth(average_s=0.01)
            d.world.advance(d.world.t + 2.5)
        r, gt = fol.bank.read(), fol.world.ground_truth(average_s=0.01)[0]
        g_true, g_desc = gravity_torque(fol.world.model, arm, r.q[:6]), gravity_torque(arm.mujoco_model(),
                                                                                        arm, r.q[:6])
        assert np.max(np.abs(g_true - g_desc) / lsb) > 20  # the error is large enough to matter
        np.testing.assert_array_less(np.abs(r.tau_m[:6] - g_true), 2 * lsb)
        np.testing.assert_allclose(gt.tau_ext[:6], 0.0, atol=1e-9)
        r_exact = exact.devices["follower"].bank.read()
        np.testing.assert_array_less(np.abs(r_exact.tau_m[:6] - gravity_torque(arm.mujoco_model(), arm,
                                                                              r_exact.q[:6])), 2 * lsb)
    finally:
        twin.close()
        exact.close()
