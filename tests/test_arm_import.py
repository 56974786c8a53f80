"""`factr2 arm import` (hardware/arms/urdf.py, urdf_import.py): built-in arms through their URDF-equivalents
give the same dynamics; each URDF defect is one line and exit 2; the UR5 URDF imports and its name works."""

from __future__ import annotations

import numpy as np
import pytest

from factr2_teleop.cli import main
from hardware.arms import load_arm
from hardware.arms.dynamics import ArmDynamics
from hardware.arms.specs import PANDA, PIPER, YAM
from hardware.arms.urdf import read_urdf
from hardware.arms.urdf_import import to_spec, user_arms_dir, write_arm
from hardware.arms.urdf_write import spec_urdf

UR5_URDF = "hardware/arms/ur5.urdf"


@pytest.fixture
def arms_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("FACTR2_ARMS", str(tmp_path / "arms"))
    return tmp_path / "arms"


@pytest.mark.parametrize("spec", [PIPER, YAM, PANDA], ids=lambda s: s.name)
def test_builtin_urdf_equivalent_imports_to_the_same_dynamics(spec, arms_dir, tmp_path):
    path = tmp_path / f"{spec.name}.urdf"
    path.write_text(spec_urdf(spec))
    builtin = load_arm(spec.name)
    write_arm(to_spec(read_urdf(path), f"imp_{spec.name}", builtin.armature), user_arms_dir())
    a, b = ArmDynamics(builtin), ArmDynamics(load_arm(f"imp_{spec.name}"))
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(builtin.limits.q_min, builtin.limits.q_max)
        qd, qdd = rng.normal(size=a.n), rng.normal(size=a.n)
        np.testing.assert_allclose(b.rnea(q, qd, qdd), a.rnea(q, qd, qdd), atol=1e-6)
        np.testing.assert_allclose(b.gravity(q), a.gravity(q), atol=1e-6)
        np.testing.assert_allclose(b.mass_matrix(q), a.mass_matrix(q), atol=1e-6)
        np.testing.assert_allclose(b.fk(q), a.fk(q), atol=1e-6)
    np.testing.assert_allclose(load_arm(f"imp_{spec.name}").limits.tau_max, builtin.limits.tau_max)


_GOOD = """<robot name="two">
  <link name="base"/>
  <link name="l1"><inertial><origin xyz="0 0 0.1"/><mass value="1"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.005" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l2">{l2_inertial}</link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-2" upper="2" effort="10" velocity="3"/></joint>
  <joint name="j2" type="{j2_type}"><parent link="{j2_parent}"/><child link="l2"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="5" velocity="3"/>{mimic}</joint>
</robot>
"""
_INERTIAL = ('<inertial><origin xyz="0.1 0 0"/><mass value="0.5"/>'
             '<inertia ixx="0.001" iyy="0.004" izz="0.004" '
             'ixy="0" ixz="0" iyz="0"/></inertial>')


def _urdf(tmp_path, **kw) -> str:
    fields = dict(l2_inertial=_INERTIAL, j2_type="revolute", j2_parent="l1", mimic="") | kw
    path = tmp_path / "arm.urdf"
    path.write_text(_GOOD.format(**fields))
    return str(path)


@pytest.mark.parametrize("defect, words", [
    (dict(l2_inertial=""), "no <inertial>"),
    (dict(j2_type="prismatic"), "cannot be driven"),
    (dict(mimic='<mimic joint="j1" multiplier="1"/>'), "mimic"),
    (dict(j2_parent="nowhere"), "broken parent chain"),
    (dict(l2_inertial=_INERTIAL.replace('izz="0.004"', 'izz="0.02"')), "triangle inequality"),
])
def test_a_broken_urdf_is_one_line_and_exit_2(defect, words, arms_dir, tmp_path, capsys):
    rc = main(["arm", "import", _urdf(tmp_path, **defect), "--name", "two"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and words in err[0], err
    assert not (arms_dir / "two.xml").exists()


def test_a_small_urdf_imports_and_its_name_works(arms_dir, tmp_path, capsys):
    assert main(["arm", "import", _urdf(tmp_path), "--name", "two", "--total-mass", "1.5"]) == 0
    out = capsys.readouterr().out
    assert "[ok] CAD masses sum to 1.500 kg" in out and "gello_two" in out
    arm = load_arm("two")
    assert arm.joint_names == ("j1", "j2") and arm.motors == ("generic", "generic")
    assert load_arm("gello_two").role == "leader"
    # the arm's own physics: the 0.5 kg link 0.1 m out along +x; holding it takes -m g x about +y
    np.testing.assert_allclose(ArmDynamics(arm).gravity(np.zeros(2))[1], -0.5 * 9.81 * 0.1, rtol=1e-3)
    assert main(["arm", "import", _urdf(tmp_path), "--name", "two"]) == 2  # no silent overwrite


def test_ur5_urdf_imports_with_its_stated_mass_flagged(arms_dir, capsys):
    assert main(["arm", "import", UR5_URDF, "--name", "ur5", "--total-mass", "18.4"]) == 0
    out = capsys.readouterr().out
    assert "[warning] CAD masses sum to 20.994 kg, stated 18.400 kg" in out
    arm = load_arm("ur5")
    assert arm.n_joints == 6 and np.allclose(arm.limits.tau_max, [150, 150, 150, 28, 28, 28])
    # UR's DH: at q = 0 the arm is stretched out along -x; the tool at x = -(a2 + a3), y = -(d4 + d6)
    ee = ArmDynamics(arm).fk(np.zeros(6))[:3, 3]
    np.testing.assert_allclose(ee, [-0.81725, -0.19145, -0.005491], atol=1e-6)


def test_twin_of_an_imported_arm_runs_teleop_with_its_generated_leader(arms_dir, tmp_path, capsys):
    """SIMULATED: a rig naming only imported arms (the follower and its generated GELLO leader)."""
    assert main(["arm", "import", _urdf(tmp_path), "--name", "two", "--q-home", "0.3,0.5"]) == 0
    rig = tmp_path / "sim-two.toml"
    rig.write_text('[rig]\nname = "sim-two"\ndescription = "imported"\nsimulated = true\n'
                   '[[leaders]]\nname = "leader"\ndriver = "dynamixel"\narm = "gello_two"\nport = "twin"\n'
                   'baud = 4000000\nids = [1, 2]\nsigns = [1, 1]\noffsets_rad = [3.14159265, 3.14159265]\n'
                   'model = "XL330-M288"\n[[followers]]\nname = "follower"\ndriver = "sim"\narm = "two"\n'
                   '[twin]\nseed = 0\nscene = "table"\n')
    capsys.readouterr()
    assert main(["teleop", "--rig", str(rig), "--seconds", "1", "--rate", "250"]) == 0
    assert "Hz (target 250)" in capsys.readouterr().out


def _ur5_rig(tmp_path) -> str:
    """A SIMULATED rig of the imported UR5 and its generated GELLO leader; no `model`: the leader's servos
    come from its description (XM430 where the XC330 cannot hold the UR5-size leader)."""
    assert main(["arm", "import", UR5_URDF, "--name", "ur5", "--q-home", "0,-1.57,1.57,-1.57,-1.57,0",
                 "--armature", "0.1,0.1,0.1,0.02,0.02,0.02"]) == 0
    rig = tmp_path / "sim-ur5.toml"
    rig.write_text('[rig]\nname = "sim-ur5"\ndescription = "imported"\nsimulated = true\n'
                   '[[leaders]]\nname = "leader"\ndriver = "dynamixel"\narm = "gello_ur5"\nport = "twin"\n'
                   'baud = 4000000\nids = [1, 2, 3, 4, 5, 6]\nsigns = [1, 1, 1, 1, 1, 1]\n'
                   f'offsets_rad = [{", ".join(["3.14159265"] * 6)}]\n'
                   '[[followers]]\nname = "follower"\ndriver = "sim"\narm = "ur5"\n'
                   '[twin]\nseed = 0\nscene = "table"\n')
    return str(rig)


def test_imported_arms_leader_servos_and_gravity_identification(arms_dir, tmp_path, capsys):
    """SIMULATED, lockstep: the generated leader's servos reach the rig from its description, its poses are
    held and the gravity fit is accepted (link 1 turns about the vertical: its mass stays as described)."""
    from calibration import leader_gravity as lg
    from hardware.connect import open_rig
    from hardware.rigs import load_rig

    rig = load_rig(_ur5_rig(tmp_path))
    assert rig.leaders[0].config.model == list(load_arm("gello_ur5").motors)
    assert rig.leaders[0].config.model[0] == "XM430-W350"
    arm = load_arm("gello_ur5")
    fast = lg.HoldGains(move_s=0.5, settle_s=0.7, measure_s=0.2)
    with open_rig(rig, clock="lockstep", seed=0) as s:
        res = lg.identify(s.leader, s.clock, arm, n_fit=6, n_check=3, gains=fast, rate_hz=200.0)
    assert res.meta["poses_fit"] >= 4 and res.meta["poses_check"] >= 2
    assert res.params[0, 0] == pytest.approx(lg.description_params(arm.pinocchio_model())[0, 0])
    lg.model_with_params(arm.pinocchio_model(), res.params)


def test_demo_journey_on_an_imported_arms_twin_in_lockstep(arms_dir, tmp_path, capsys):
    """SIMULATED: `factr2 demo` (virtual operator, table task, disturbance-observer feedback) on the twin of
    the imported UR5 with its generated leader, lockstep at 500 Hz, no command beyond the safety limits."""
    import json

    rig = _ur5_rig(tmp_path)
    out = tmp_path / "demo.json"
    assert main(["demo", "--rig", rig, "--headless", "--seconds", "1", "--mode", "dob", "--clock", "lockstep",
                 "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["clock"] == "lockstep" and d["ticks"] == 500 and d["loop_hz"] == pytest.approx(500.0)
    assert d["max_command_violation"] == 0 and np.isfinite(d["tau_ext_l1_free"])
