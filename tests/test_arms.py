"""Arm descriptions: MJCF files load in MuJoCo and pinocchio and agree; limits; scenes; bad files."""

from __future__ import annotations

import math
import re

import mujoco
import numpy as np
import pytest

from hardware.arms import ARMS_DIR, list_arms, load_arm
from hardware.arms import generate as gen
from hardware.arms.dynamics import ArmDynamics, gravity
from hardware.errors import ConfigError

ARMS = ["piper", "yam", "panda", "gello_piper", "gello_yam"]
SCENE_ARMS = ["piper", "yam", "panda"]
TOL = 1e-6  # N*m, kg*m^2
NUMBER = r"(?<![\w.])-?\d+(?:\.\d+)?(?:e[-+]?\d+)?"


def _poses(arm, k=50, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(arm.limits.q_min, arm.limits.q_max, size=(k, arm.n_joints))


def _mj(arm):
    m = arm.mujoco_model()
    return m, mujoco.MjData(m), *arm.mujoco_indices(m)


def test_list_arms_has_every_shipped_arm():
    assert set(ARMS) <= set(list_arms())


def _split_numbers(text: str) -> tuple[str, np.ndarray]:
    nums = re.findall(NUMBER, text)
    return re.sub(NUMBER, "#", text), np.array([float(x) for x in nums])


def test_generated_files_match_the_tables():
    # numbers compared to 1e-9 relative (a different libm may round sin/cos in the last digit)
    for path, text in gen.outputs().items():
        have_t, have_n = _split_numbers(path.read_text())
        want_t, want_n = _split_numbers(text)
        stale = f"{path.name} is stale: run python -m hardware.arms.generate"
        assert have_t == want_t and have_n.shape == want_n.shape, stale
        np.testing.assert_allclose(have_n, want_n, rtol=1e-9, atol=1e-12, err_msg=stale)


@pytest.mark.parametrize("name", ARMS)
def test_arm_loads_in_mujoco_and_pinocchio(name):
    arm = load_arm(name)
    m = arm.mujoco_model()
    model = arm.pinocchio_model()
    assert model.nq == model.nv == arm.n_joints
    assert tuple(model.names[1:]) == arm.joint_names
    assert len(arm.sha256) == 64 and arm.mjcf_path == ARMS_DIR / f"{name}.xml"
    assert load_arm(name) is arm and arm.mujoco_model() is m and arm.pinocchio_model() is model  # cached
    assert not np.any(m.body_gravcomp), "gravcomp hides gravity from the motor torques"
    assert arm.gripper_joints and arm.role in ("follower", "leader", "sim")
    assert model.existFrame(arm.ee_site)


@pytest.mark.parametrize("name", ARMS)
def test_gravity_and_bias_agree_with_mujoco(name):
    arm = load_arm(name)
    m, d, qa, da = _mj(arm)
    dyn = ArmDynamics(arm)
    rng = np.random.default_rng(1)
    worst_g = worst_c = 0.0
    for q in _poses(arm):
        d.qpos[:] = m.qpos0  # gripper held at its locked (closed) position
        d.qpos[qa] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        worst_g = max(worst_g, np.abs(d.qfrc_bias[da] - dyn.gravity(q)).max())
        qd = rng.normal(size=arm.n_joints)
        d.qvel[da] = qd
        mujoco.mj_forward(m, d)
        worst_c = max(worst_c, np.abs(d.qfrc_bias[da] - dyn.nonlinear_effects(q, qd)).max())
    assert worst_g < TOL and worst_c < TOL


@pytest.mark.parametrize("name", ARMS)
def test_mass_matrix_agrees_with_mujoco_armature_included(name):
    arm = load_arm(name)
    m, d, qa, da = _mj(arm)
    dyn = ArmDynamics(arm)
    full = np.zeros((m.nv, m.nv))
    for q in _poses(arm, k=20):
        d.qpos[:] = m.qpos0
        d.qpos[qa] = q
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, full)
        mass = dyn.mass_matrix(q)
        np.testing.assert_allclose(mass, full[np.ix_(da, da)], atol=TOL, rtol=0)
        np.testing.assert_allclose(mass, mass.T, atol=1e-12)
    np.testing.assert_allclose(dyn.armature, arm.armature)


@pytest.mark.parametrize("name", ARMS)
def test_ee_pose_and_jacobian_agree_with_mujoco_site(name):
    arm = load_arm(name)
    m, d, qa, da = _mj(arm)
    dyn = ArmDynamics(arm)
    sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, arm.ee_site)
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for q in _poses(arm, k=10, seed=3):
        d.qpos[:] = m.qpos0
        d.qpos[qa] = q
        mujoco.mj_forward(m, d)
        pose = dyn.fk(q)
        np.testing.assert_allclose(pose[:3, 3], d.site_xpos[sid], atol=1e-9)
        np.testing.assert_allclose(pose[:3, :3], d.site_xmat[sid].reshape(3, 3), atol=1e-9)
        mujoco.mj_jacSite(m, d, jp, jr, sid)
        np.testing.assert_allclose(dyn.jacobian(q), np.vstack([jp[:, da], jr[:, da]]), atol=1e-9)


@pytest.mark.parametrize("name", ARMS)
def test_regressor_times_parameters_is_rnea(name):
    dyn = ArmDynamics(name)
    rng = np.random.default_rng(2)
    Q = _poses(dyn.arm, k=20, seed=4)
    QD, QDD = rng.normal(size=Q.shape), rng.normal(size=Q.shape)
    tau = dyn.rnea_batch(Q, QD, QDD)
    p, p_rigid = dyn.parameters(), dyn.parameters(armature=False)
    assert p.shape == (11 * dyn.n,) and p_rigid.shape == (10 * dyn.n,)
    Y = dyn.regressor_batch(Q, QD, QDD)
    np.testing.assert_allclose(Y @ p, tau, atol=1e-9)
    for t in range(3):
        np.testing.assert_allclose(dyn.regressor(Q[t], QD[t], QDD[t]) @ p, tau[t], atol=1e-9)
        rigid = dyn.regressor(Q[t], QD[t], QDD[t], armature=False) @ p_rigid
        np.testing.assert_allclose(rigid + dyn.armature * QDD[t], tau[t], atol=1e-9)
    assert dyn.friction_regressor(QD[0]).shape == (dyn.n, 2 * dyn.n)


def test_batches_match_single_calls_and_identities_hold():
    dyn = ArmDynamics("piper")
    rng = np.random.default_rng(5)
    Q = _poses(dyn.arm, k=8, seed=6)
    QD, QDD = rng.normal(size=Q.shape), rng.normal(size=Q.shape)
    G, N, R = dyn.gravity_batch(Q), dyn.nonlinear_effects_batch(Q, QD), dyn.rnea_batch(Q, QD, QDD)
    M, C = dyn.mass_matrix_batch(Q), dyn.coriolis_matrix_batch(Q, QD)
    F, J = dyn.fk_batch(Q), dyn.jacobian_batch(Q)
    for t in range(len(Q)):
        np.testing.assert_allclose(G[t], dyn.gravity(Q[t]), atol=1e-12)
        np.testing.assert_allclose(R[t], M[t] @ QDD[t] + C[t] @ QD[t] + G[t], atol=1e-9)
        np.testing.assert_allclose(N[t], C[t] @ QD[t] + G[t], atol=1e-9)
        np.testing.assert_allclose(F[t], dyn.fk(Q[t]), atol=1e-12)
        np.testing.assert_allclose(J[t], dyn.jacobian(Q[t]), atol=1e-12)
    np.testing.assert_allclose(gravity("piper", Q[0]), G[0], atol=1e-12)
    with pytest.raises(ValueError):
        dyn.gravity(np.zeros(5))
    with pytest.raises(ValueError):
        dyn.rnea_batch(Q, QD[:3], QDD)


def test_coriolis_matrix_makes_mdot_minus_2c_skew():
    dyn = ArmDynamics("yam")
    q, qd = dyn.arm.q_home + 0.1, np.linspace(-1.0, 1.0, dyn.n)
    h = 1e-6
    mdot = (dyn.mass_matrix(q + h * qd) - dyn.mass_matrix(q - h * qd)) / (2 * h)
    s = mdot - 2 * dyn.coriolis_matrix(q, qd)
    np.testing.assert_allclose(s, -s.T, atol=1e-6)


def test_piper_and_yam_limits_parse():
    piper = load_arm("piper").limits
    deg = np.rad2deg
    np.testing.assert_allclose(deg(piper.q_min), [-150, 0, -170, -100, -70, -120], atol=1e-9)
    np.testing.assert_allclose(deg(piper.q_max), [150, 180, 0, 100, 70, 120], atol=1e-9)
    assert np.all(piper.tau_max > 0) and np.all(np.isfinite(piper.tau_rate_max)) and np.all(piper.v_max > 1)
    yam = load_arm("yam")
    np.testing.assert_allclose(yam.armature, [0.032] * 3 + [0.0018] * 3)
    np.testing.assert_allclose(yam.limits.tau_max, [27, 27, 27, 7, 7, 7])
    assert load_arm("piper").gripper_range == (0.0, 0.035) and load_arm("piper").gripper_stroke_gain == 2.0
    panda = load_arm("panda").limits
    np.testing.assert_allclose(panda.tau_max, [87] * 4 + [12] * 3)
    for name in ARMS:
        arm = load_arm(name)
        assert np.all(arm.q_home >= arm.limits.q_min) and np.all(arm.q_home <= arm.limits.q_max)


def test_masses_are_realistic():
    total = {n: float(np.sum(load_arm(n).mujoco_model().body_mass)) for n in ARMS}
    assert 3.8 < total["piper"] < 4.6  # AgileX: 4.2 kg
    assert 4.0 < total["yam"] < 6.0
    assert 15.0 < total["panda"] < 20.0
    for leader in ("gello_piper", "gello_yam"):
        assert 0.2 < total[leader] < 0.7
        assert load_arm(leader).gripper_stroke_gain == 1.0
        g = np.abs(ArmDynamics(leader).gravity_batch(_poses(load_arm(leader), k=50))).max(axis=0)
        assert np.all(g < load_arm(leader).limits.tau_max)  # servos can hold the leader up


# -- bad input ------------------------------------------------------------------------------------
RATE = '<numeric name="factr2.tau_rate_max" data='


def _piper_text() -> str:
    return (ARMS_DIR / "piper.xml").read_text()


@pytest.mark.parametrize("edit, needle", [
    (lambda s: s.replace('<numeric name="factr2.v_max"', '<numeric name="factr2.vmax"'), "factr2.v_max"),
    (lambda s: s.replace('name="factr2.arm_joints" data="joint1', 'name="factr2.arm_joints" data="jointX'),
     "jointX"),
    (lambda s: s.replace(RATE + '"500 ', RATE + '"'), "factr2.tau_rate_max"),
    (lambda s: s.replace(RATE + '"500', RATE + '"-5'), "tau_rate_max"),
    (lambda s: s.replace('actuatorfrcrange="-25 25"', "", 1), "actuatorfrcrange"),
    (lambda s: s.replace("<worldbody>", "<worldbody><oops", 1), "compile"),
    (lambda s: s.replace('name="factr2.ee_site" data="ee"/>', 'name="factr2.ee_site" data="tip"/>'), "tip"),
    (lambda s: "", "compile"),
])
def test_bad_file_raises_config_error_naming_file_and_field(tmp_path, edit, needle):
    bad = tmp_path / "bad_arm.xml"
    text = edit(_piper_text())
    assert text != _piper_text()
    bad.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_arm(bad)
    msg = str(err.value)
    assert "bad_arm.xml" in msg and needle in msg and "fix:" in msg
    assert "\n" not in msg


def test_unknown_name_missing_file_and_scene(tmp_path):
    with pytest.raises(ConfigError, match="unknown arm 'ur99'.*piper"):
        load_arm("ur99")
    with pytest.raises(ConfigError, match="not found"):
        load_arm(tmp_path / "nope.xml")
    with pytest.raises(ConfigError, match="no scene 'kitchen'"):
        load_arm("piper").scene_path("kitchen")
    with pytest.raises(ConfigError, match="no scene"):
        load_arm("gello_piper").scene_path()


def test_copied_file_loads_by_path(tmp_path):
    copy = tmp_path / "my_piper.xml"
    copy.write_text(_piper_text())
    arm = load_arm(str(copy))
    assert arm.name == "my_piper" and arm.sha256 == load_arm("piper").sha256
    assert arm.pinocchio_model().nq == 6


# -- scenes ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", SCENE_ARMS)
def test_scene_contacts_are_stable_at_1khz(name):
    arm = load_arm(name)
    m = mujoco.MjModel.from_xml_path(str(arm.scene_path("table")))
    assert math.isclose(m.opt.timestep, 0.001)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    qa, da = arm.mujoco_indices(m)
    np.testing.assert_allclose(d.qpos[qa], arm.q_home)
    dyn = ArmDynamics(arm)
    box = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "box")
    mujoco.mj_forward(m, d)
    x0 = d.xpos[box].copy()
    n_arm, worst_pen, most = arm.n_joints, 0.0, 0
    kp = np.where(arm.limits.tau_max > 20, 200.0, 30.0)
    for k in range(2500):
        q, v = d.qpos[qa], d.qvel[da]
        # hold the arm at home for 1.5 s (PD + gravity from pinocchio), then let it fall onto the table
        tau = kp * (arm.q_home - q) - 0.05 * kp * v + dyn.gravity(q) if k < 1500 else np.zeros(n_arm)
        d.ctrl[:n_arm] = np.clip(tau, -arm.limits.tau_max, arm.limits.tau_max)
        d.xfrc_applied[box, 0] = 2.5 if 500 <= k < 700 else 0.0  # push the box: it slides, then stops
        mujoco.mj_step(m, d)
        if d.ncon:
            most = max(most, d.ncon)
            if k > 400 and k < 1500 or k > 2300:
                worst_pen = min(worst_pen, float(d.contact.dist[: d.ncon].min()))
    assert np.all(np.isfinite(d.qpos)) and not any(w.number for w in d.warning)
    assert most <= 16
    assert worst_pen > -0.002, f"resting penetration {worst_pen} m"
    moved = d.xpos[box] - x0
    assert 0.05 < moved[0] < 0.4 and abs(moved[1]) < 0.01  # slid forward, stayed on the table
    assert abs(d.xpos[box][2] - 0.03) < 0.002 and np.abs(d.qvel[-6:]).max() < 1e-2  # at rest on the top


@pytest.mark.parametrize("name", ["piper", "yam", "panda"])
def test_gripper_actuator_moves_both_fingers(name):
    arm = load_arm(name)
    m = arm.mujoco_model()
    d = mujoco.MjData(m)
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in arm.gripper_joints]
    act = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, arm.gripper_joints[0])
    lo, hi = arm.gripper_range
    qa, _ = arm.mujoco_indices(m)
    d.qpos[qa] = arm.q_home
    dyn = ArmDynamics(arm)
    target = lo + 0.8 * (hi - lo)
    for _ in range(600):
        d.ctrl[: arm.n_joints] = dyn.gravity(d.qpos[qa])  # arm motors: hold the arm roughly still
        d.ctrl[act] = target
        mujoco.mj_step(m, d)
    finger, mirror = d.qpos[m.jnt_qposadr[ids[0]]], d.qpos[m.jnt_qposadr[ids[1]]]
    assert abs(finger - target) < 0.1 * (hi - lo) and abs(mirror - finger) < 1e-3
