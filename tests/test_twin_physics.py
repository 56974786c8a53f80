"""Physics of the twin's motor banks (SIMULATED arms): gravity, friction, the undeclared hook, pushes,
contacts and determinism. Everything runs through MujocoBank directly or the Twin without drivers."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from hardware.arms import load_arm
from hardware.arms.dynamics import gravity
from hardware.sim import actuators as act
from hardware.sim.actuators import Effects
from hardware.sim.presets import arm_params
from hardware.sim.world import MujocoWorld

POSES = [np.array([0.3, 1.0, -0.8, 0.2, 0.5, -0.3]), np.array([-0.5, 0.6, -1.4, -0.4, -0.3, 0.8])]


def _piper_world(effects: Effects, scene: str | None = None, hook=None, seed: int = 0):
    arm = load_arm("piper")
    path = arm.scene_path(scene) if scene else arm.mjcf_path
    world = MujocoWorld(mujoco.MjModel.from_xml_path(str(path)))
    bank = world.add_bank(list(arm.joint_names), arm_params("piper", effects=effects), seed=seed, hook=hook)
    return arm, world, bank


def _hold(world, bank, q, seconds=1.5):
    world.set_qpos(bank, q)
    bank.enable(np.arange(bank.n), True)
    bank.command_position(np.arange(bank.n), q)
    world.advance(world.t + seconds)


@pytest.mark.parametrize("q", POSES)
def test_static_torque_is_pinocchio_gravity_with_effects_off(q):
    arm, world, bank = _piper_world(dataclasses.replace(Effects.none(), quantisation=True))
    _hold(world, bank, q, 3.0)
    r = bank.read()
    g = gravity(arm, r.q)
    lsb = bank.p.current_lsb * bank.p.kt  # one firmware current unit [N*m]
    assert np.all(np.abs(r.q_dot) < 2e-4)
    assert np.max(np.abs(g)) > 1.0  # the pose really loads the joints
    np.testing.assert_array_less(np.abs(r.tau_m - g), lsb)
    assert np.all(np.abs(r.tau_m / bank.p.current_lsb / bank.p.kt - np.round(r.current / bank.p.current_lsb))
                  < 1e-6)  # reported in whole firmware units


def test_slow_velocity_sweep_reproduces_friction_curve():
    fx = dataclasses.replace(Effects.none(), friction=True, stribeck=True)
    arm, world, bank = _piper_world(fx)
    q0 = np.array([-1.2, 1.0, -0.8, 0.0, 0.3, 0.0])
    _hold(world, bank, q0, 0.5)
    p = bank.p
    for v in (0.03, 0.1, 0.3, 1.0, -0.1, -0.5):
        world.set_qpos(bank, q0 if v > 0 else q0 + np.array([2.4, 0, 0, 0, 0, 0]))
        bank.enable(np.arange(6), False)
        bank.enable(np.arange(6), True)
        bank.set_speed([0], abs(v) / p.pos_vel_max[0])
        goal = bank.theta.copy()
        goal[0] += np.sign(v) * 3.0
        bank.command_position(np.arange(6), goal)
        world.advance(world.t + 1.2)  # the position loop's integrator settles: constant velocity
        taus, vels = [], []
        for _ in range(200):
            world.step()
            taus.append(bank.read().tau_m[0])
            vels.append(world.data.qvel[bank.dadr[0]])
        vm = float(np.mean(vels))
        assert abs(vm - v) < 0.02 * abs(v) + 1e-3, (v, vm)
        expected = act.friction_torque(np.array([vm]), p.coulomb[:1], p.viscous[:1], p.stribeck[:1],
                                       p.stribeck_vel[:1], p.smooth_vel[:1])[0]
        assert abs(expected) > 0.1
        # joint 1 has a vertical axis: no gravity, and M does not depend on q1, so tau_m = friction
        assert float(np.mean(taus)) == pytest.approx(expected, rel=0.03, abs=0.01), v


def _hook(t, q, qd):
    return 0.4 * np.sin(q) + np.array([0.1, -0.2, 0.3, 0.05, -0.05, 0.02])


def test_hook_changes_measured_torque_by_exactly_its_value():
    eff = dataclasses.replace(Effects.none(), quantisation=False)
    q = POSES[0]
    arm, w0, b0 = _piper_world(eff)
    _, w1, b1 = _piper_world(eff, hook=_hook)
    _hold(w0, b0, q, 3.0)
    _hold(w1, b1, q, 3.0)
    r0, r1 = b0.read(), b1.read()
    np.testing.assert_allclose(r1.q, r0.q, atol=1e-3)  # the integrators absorb it: (nearly) the same pose
    # measured torque = gravity + hook: the difference is exactly the hook (gravity taken at each pose)
    d_meas = (r1.tau_m - gravity(arm, r1.q)) - (r0.tau_m - gravity(arm, r0.q))
    np.testing.assert_allclose(d_meas, _hook(0.0, r1.q, 0 * q), atol=1e-3)


def test_hook_is_not_external_torque_in_free_motion():
    _, world, bank = _piper_world(Effects(), hook=_hook)
    world.set_qpos(bank, POSES[0])
    bank.enable(np.arange(6), True)
    bank.command_position(np.arange(6), POSES[1])
    for _ in range(5):
        world.advance(world.t + 0.1)
        gt = world.ground_truth()[0]
        assert np.any(np.abs(gt.q_dot) > 0.05)
        np.testing.assert_array_equal(gt.tau_ext, 0.0)
        assert not gt.contact
        np.testing.assert_allclose(gt.tau_load - bank.tau_ripple, _hook(0, gt.q, gt.q_dot), atol=0.05)
    assert bank.hook_errors == 0


def test_push_shows_in_ground_truth_and_in_measured_torque():
    eff = dataclasses.replace(Effects.none(), quantisation=False)
    _, world, bank = _piper_world(eff)
    _hold(world, bank, POSES[0], 1.5)
    before = bank.read().tau_m
    world.push("link6", [0.0, 0.0, -15.0], duration_s=3.0)
    world.advance(world.t + 2.0)
    gt = world.ground_truth()[0]
    assert np.max(np.abs(gt.tau_push)) > 1.0
    np.testing.assert_allclose(gt.tau_ext, gt.tau_push)
    # paper convention: tau_ext = tau_m - tau_free (tau_free = the torque before the push, same pose)
    np.testing.assert_allclose(bank.read().tau_m - before, gt.tau_ext, atol=0.02)
    world.advance(world.t + 1.5)
    assert np.all(world.ground_truth()[0].tau_push == 0.0)  # the push ended


def test_ground_truth_is_the_mean_over_the_sample_period():
    """A push lasting 4 of the last 10 physics steps: the 10-step mean is 0.4 of it, the last step 0."""
    eff = dataclasses.replace(Effects.none(), quantisation=False)
    _, world, bank = _piper_world(eff)
    world.set_substeps(2)
    assert not world.keep_truth  # no per-step history until someone asks for a mean
    world.ground_truth(average_s=0.01)
    assert world.keep_truth
    _hold(world, bank, POSES[0], 0.5)
    world.push("link6", [0.0, 0.0, -15.0], duration_s=0.004)
    full = world.ground_truth()[0].tau_push  # the push as it acts now
    assert np.max(np.abs(full)) > 1.0
    for _ in range(5):  # 5 control ticks = 10 physics steps of 1 ms; the push acts in the first 4
        world.step()
    step = float(world.model.opt.timestep)
    mean = world.ground_truth(average_s=10 * step)[0]
    np.testing.assert_allclose(mean.tau_push, 0.4 * full, rtol=0.02, atol=1e-3)  # the pose barely moves
    np.testing.assert_allclose(mean.tau_ext, mean.tau_push)
    np.testing.assert_array_equal(world.ground_truth()[0].tau_push, 0.0)
    np.testing.assert_array_equal(world.ground_truth(average_s=4 * step)[0].tau_push, 0.0)


def test_averaged_truth_of_a_table_impact_is_the_mean_of_its_physics_steps():
    """The gripper driven 4 cm into the table: the impact is a few physics steps long. Each 10 ms mean equals
    the mean of its physics steps' contact torque (what a drive feels); the last step alone, read at the
    same instants, is off from it by tens of N*m during the impact (aliasing)."""
    eff = dataclasses.replace(Effects.none(), quantisation=False)
    _, world, bank = _piper_world(eff, scene="table")
    world.set_substeps(2)
    world.keep_truth = True  # keep every physics step (a first averaged read does the same)
    q_up = np.array([0.0, 1.6, -1.0, 0.0, 0.9, 0.0])
    _hold(world, bank, q_up, 0.5)
    bank.command_position(np.arange(6), q_up + np.array([0, 0.4, 0, 0, 0, 0]))
    per_step, means, points = [], [], []
    for tick in range(1000):
        world.step()
        per_step.extend(np.zeros(6) if s[1] is None else -s[1][bank.dadr] for s in list(world._truth)[-2:])
        if tick % 5 == 4:
            means.append(world.ground_truth(average_s=0.01)[0].tau_contact)
            points.append(world.ground_truth()[0].tau_contact)
    per_step, means, points = np.array(per_step), np.array(means), np.array(points)
    np.testing.assert_allclose(means, per_step.reshape(-1, 10, 6).mean(axis=1), atol=1e-9)
    assert np.abs(means).max() > 1.0  # it pressed on the table
    assert np.abs(means - points).max() > 5.0


def test_table_contact_is_external_and_flagged():
    eff = dataclasses.replace(Effects.none(), quantisation=False)
    _, world, bank = _piper_world(eff, scene="table")
    q_up = np.array([0.0, 1.6, -1.0, 0.0, 0.9, 0.0])  # gripper 7 cm above the table
    _hold(world, bank, q_up, 1.0)
    gt = world.ground_truth()[0]
    assert not gt.contact
    q_down = q_up + np.array([0, 0.4, 0, 0, 0, 0])  # 4 cm into the table
    bank.command_position(np.arange(6), q_down)
    world.advance(world.t + 2.0)
    gt = world.ground_truth()[0]
    assert gt.contact
    assert np.max(np.abs(gt.tau_contact)) > 0.5
    g = gravity(load_arm("piper"), gt.q)
    np.testing.assert_allclose(bank.read().tau_m - g, gt.tau_ext, atol=0.05)


def test_backlash_play_and_thermal_are_stable_and_bounded():
    w = act.backlash_play(np.array([0.0, 1.0]), np.array([0.5, 0.0]), np.array([0.2, 0.2]))
    np.testing.assert_allclose(w, [0.1, 0.9])
    t = np.array([25.0])
    for _ in range(1000):
        t = act.thermal_step(t, np.array([2.0]), np.array([1.0]), np.array([3.0]), np.array([10.0]), 25.0,
                             0.1)
    assert t[0] == pytest.approx(25.0 + 4.0 * 3.0, rel=1e-3)
    f = act.friction_torque(np.linspace(-1e-3, 1e-3, 101), 0.3, 0.1, 0.1, 0.05, 0.005)
    assert np.all(np.diff(f) > 0)  # smooth and monotone through zero at low speed


def test_lockstep_bank_is_deterministic_for_a_seed():
    def run(seed):
        _, world, bank = _piper_world(Effects(), seed=seed)
        _hold(world, bank, POSES[0], 0.2)
        bank.command_position(np.arange(6), POSES[1])
        out = []
        for _ in range(50):
            world.advance(world.t + 0.004)
            r = bank.read()
            out.append(np.concatenate([r.q, r.q_dot, r.current, r.temperature]))
        return np.array(out)
    a, b, c = run(3), run(3), run(4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_decimated_control_keeps_static_torque_and_stiff_mit_gains_stable():
    # control at 500 Hz over 1 kHz physics: the static torque is still gravity
    arm, world, bank = _piper_world(dataclasses.replace(Effects.none(), quantisation=True))
    world.set_substeps(2)
    _hold(world, bank, POSES[1], 3.0)
    r = bank.read()
    np.testing.assert_array_less(np.abs(r.tau_m - gravity(arm, r.q)), 2 * bank.p.current_lsb * bank.p.kt)
    # the largest MIT damping the safety layer allows on the lightest YAM joint stays stable (implicit kd)
    yam = load_arm("yam")
    w = MujocoWorld(mujoco.MjModel.from_xml_path(str(yam.mjcf_path)))
    b = w.add_bank(list(yam.joint_names), arm_params("yam"), seed=1)
    n = b.n
    b.command_mit(np.arange(n), np.zeros(n), np.zeros(n), np.full(n, 500.0), np.full(n, 5.0), np.zeros(n))
    w.advance(1.0)
    gt = w.ground_truth()[0]
    assert np.all(np.isfinite(gt.q)) and np.max(np.abs(gt.q_dot)) < 0.05


def test_linearised_friction_matches_the_curve_and_damps():
    p = arm_params("piper", effects=Effects()).sized(6)
    p.coulomb[:], p.viscous[:] = 0.3, 0.1
    for v in (np.linspace(-2, 2, 6), np.zeros(6), np.full(6, 1e-3)):
        d, f0 = act.linearised_friction(v, p)
        exact = act.friction_torque(v, p.coulomb, p.viscous, p.stribeck, p.stribeck_vel, p.smooth_vel)
        np.testing.assert_allclose(f0 + d * v, exact, rtol=1e-12, atol=1e-12)
        assert np.all(d >= p.viscous)
