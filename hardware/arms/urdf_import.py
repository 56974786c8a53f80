"""`factr2 arm import`: a checked URDF -> an arm description in the user's arm folder (docs/arms_import.md).

    findings = check(arm, total_mass_kg)          # [(level, text)], level "error" | "warning" | "ok"
    spec = to_spec(arm, "ur5")                    # hardware.arms.specs.ArmSpec (the built-in arms' tables)
    paths = write_arm(spec, user_arms_dir())      # NAME.xml, scenes/NAME_table.xml, gello_NAME.xml
    agreement(path, load_arm(paths[0]))           # pinocchio vs MuJoCo vs the written description

The user's arm folder is $FACTR2_ARMS, default $XDG_CONFIG_HOME/factr2/arms (~/.config/factr2/arms);
hardware.arms.load_arm finds a name there after the built-in ones.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from hardware.arms.specs import SERVOS, TAU_RATE_RISE_S, ArmSpec, Finger, Geom, Link, gello_from
from hardware.arms.urdf import CONTINUOUS_RANGE_RAD, UrdfArm, UrdfError, matrix_quat
from hardware.switches import switches

DEFAULT_ARMATURE = 0.0  # kg*m^2: a URDF carries no rotor inertia (the identified prior fits it)
TOTAL_MASS_TOL = 0.10  # CAD total vs the stated mass: a warning beyond this fraction
AGREE_TOL = 1e-6  # relative: pinocchio vs MuJoCo vs the written description
COLLISION_RADIUS_M = 0.03  # the twin's simple capsules along each link (no meshes read)
GENERIC_MOTOR = "generic"  # hardware.sim.presets: the twin's default actuator effects, reported in N*m
LEADER_SERVOS = ("XC330-M288", "XL330-M288")  # GELLO leader: the bigger servo on the first half of the joints
LEADER_BIG_SERVO = "XM430-W350"  # where those cannot hold the leader up
LEADER_HOLD_FRAC = 0.5  # a servo holds at most this fraction of its torque limit against gravity
# A URDF whose root has no <inertial> (a "world" or "base_footprint" link): the fixed base body gets this
# placeholder (MuJoCo refuses a zero inertia; a body welded to the world changes no joint torque).
BASE_PLACEHOLDER = (1.0, (1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0))  # kg, kg*m^2
NAME_RE = re.compile(r"^[a-z][a-z0-9_]{0,31}$")


def user_arms_dir() -> Path:
    """The user's arm folder: $FACTR2_ARMS, else $XDG_CONFIG_HOME/factr2/arms (hardware.switches)."""
    return switches().arms


def check(arm: UrdfArm, total_mass_kg: float | None = None) -> list[tuple[str, str]]:
    """Physical checks of the chain: positive masses, inertias that satisfy the triangle inequality, limits
    present, the CAD total against a stated one. Errors make the import fail (exit 2)."""
    out = list(arm.findings)
    for j, b in zip(arm.joints, arm.bodies):
        if not b.mass > 0:
            out.append(("error", f"link after joint '{j.name}': mass {b.mass:g} kg (must be > 0)"))
            continue
        ev = np.sort(np.linalg.eigvalsh(0.5 * (b.inertia + b.inertia.T)))
        if ev[0] <= 0 or ev[0] + ev[1] < ev[2] * (1 - 1e-9):
            out.append(("error", f"link after joint '{j.name}': inertia not physical (principal moments "
                                 f"{ev[0]:.3g}, {ev[1]:.3g}, {ev[2]:.3g} kg*m^2 break positivity or the "
                                 "triangle inequality)"))
        if j.kind == "continuous":
            out.append(("warning", f"joint '{j.name}' is continuous: the twin limits it to "
                                   f"+-{CONTINUOUS_RANGE_RAD:.2f} rad"))
        elif j.lower is None or j.upper is None or not j.upper > j.lower:
            out.append(("error", f"joint '{j.name}': no position limits (<limit lower upper>) [rad]"))
        for what, val in (("effort", j.effort), ("velocity", j.velocity)):
            if val is None or not val > 0:
                out.append(("error", f"joint '{j.name}': <limit {what}> missing or not > 0 "
                                     f"({'N*m' if what == 'effort' else 'rad/s'})"))
    out.append(("ok", f"{len(arm.joints)} moving joints, CAD mass {arm.total_mass:.3f} kg "
                      f"(moving links {arm.total_mass - arm.base.mass:.3f} kg)"))
    if total_mass_kg is not None:
        off = arm.total_mass / total_mass_kg - 1
        level = "warning" if abs(off) > TOTAL_MASS_TOL else "ok"
        out.append((level, f"CAD masses sum to {arm.total_mass:.3f} kg, stated {total_mass_kg:.3f} kg "
                           f"({off:+.0%}); the identified prior corrects the inertials on calibration data, "
                           "the twin uses the CAD values"))
    out.append(("warning", "meshes are not read: the twin collides with capsules along the links, "
                           "the URDF has no rotor inertia (armature 0 unless --armature)"))
    return out


def _tuple6(b) -> tuple:
    i = b.inertia
    return (i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])


def _capsule(end: np.ndarray) -> tuple:
    """A capsule from the joint to the next one, its start pulled in by 1.2 radii so that the first link
    does not sit inside the table the base stands on."""
    length = float(np.linalg.norm(end))
    if length < 3 * COLLISION_RADIUS_M:  # a short link (a wrist, the flange): a sphere where it ends
        tip = tuple(float(v) for v in end)
        return () if length == 0 else (Geom("sphere", (COLLISION_RADIUS_M,), pos=tip),)
    start = end * (1.2 * COLLISION_RADIUS_M / length)
    return (Geom("capsule", (COLLISION_RADIUS_M,), fromto=tuple(float(v) for v in (*start, *end))),)


def to_spec(arm: UrdfArm, name: str, armature=DEFAULT_ARMATURE) -> ArmSpec:
    """The arm's tables (specs.ArmSpec) from a checked chain; armature [kg*m^2] one value or one per joint."""
    n = len(arm.joints)
    arm_a = np.broadcast_to(np.asarray(armature, float), (n,))
    links = []
    for k, (j, b) in enumerate(zip(arm.joints, arm.bodies)):
        lo, hi = ((-CONTINUOUS_RANGE_RAD, CONTINUOUS_RANGE_RAD) if j.kind == "continuous"
                  else (float(j.lower), float(j.upper)))
        end = arm.joints[k + 1].xyz if k + 1 < n else arm.ee_pos
        links.append(Link(j.name, pos=tuple(float(v) for v in j.xyz), rpy=tuple(float(v) for v in j.rpy),
                          axis=tuple(float(v) for v in j.axis), range=(lo, hi), mass=float(b.mass),
                          com=tuple(float(v) for v in b.com), inertia=tuple(float(v) for v in _tuple6(b)),
                          tau_max=float(j.effort), v_max=float(j.velocity), armature=float(arm_a[k]),
                          damping=float(j.damping), frictionloss=float(j.friction),
                          tau_rate_max=float(j.effort) / TAU_RATE_RISE_S, geoms=_capsule(end)))
    home = tuple(float(min(max(0.0, lk.range[0]), lk.range[1])) for lk in links)
    base = arm.base
    b_mass, b_inertia = ((float(base.mass), tuple(float(v) for v in _tuple6(base))) if base.mass > 0
                         else BASE_PLACEHOLDER)
    return ArmSpec(name=name, role="follower", title=f"{arm.robot} (imported from {arm.path.name})",
                   base_mass=b_mass, base_com=tuple(float(v) for v in base.com),
                   base_inertia=b_inertia, base_geoms=(), links=tuple(links),
                   ee_pos=tuple(float(v) for v in arm.ee_pos), ee_quat=matrix_quat(arm.ee_rot), q_home=home,
                   motors=(GENERIC_MOTOR,) * n)


def _gravity_bound(lead: ArmSpec) -> np.ndarray:
    """Per joint, an upper bound of the leader's static gravity torque [N*m]: every distal link's mass at
    the sum of the link offsets out to it (the arm stretched horizontally)."""
    links = lead.links
    out = np.zeros(len(links))
    for k in range(len(links)):
        reach = 0.0
        for i in range(k, len(links)):
            if i > k:
                reach += float(np.linalg.norm(links[i].pos))
            out[k] += links[i].mass * (reach + float(np.linalg.norm(links[i].com)))
    return 9.81 * out


def leader_spec(follower: ArmSpec) -> ArmSpec:
    """A GELLO-style leader of an imported follower, generated as for the built-in arms (specs.gello_from):
    XC330 on the first half of the joints, XL330 on the rest, and an XM430 wherever that servo could not
    hold LEADER_HOLD_FRAC of its stall torque against the leader's own weight (a UR5-size leader)."""
    n = len(follower.links)
    servos = [LEADER_SERVOS[0] if k < (n + 1) // 2 else LEADER_SERVOS[1] for k in range(n)]
    trigger = Finger("trigger", kind="hinge", pos=(0.0, 0.03, 0.0), axis=(1, 0, 0), range=(0.0, 0.8),
                     mass=0.010, com=(0.0, 0.0, 0.03), inertia=(3.2e-6, 3.1e-6, 3e-7, 0.0, 0.0, 0.0))
    for _ in range(3):  # a bigger servo is heavier: re-check with it
        lead = gello_from(follower, f"gello_{follower.name}", tuple(servos), trigger)
        load = _gravity_bound(lead)
        bigger = [k for k in range(n) if load[k] > LEADER_HOLD_FRAC * SERVOS[servos[k]]["tau_max"]
                  and servos[k] != LEADER_BIG_SERVO]
        if not bigger:
            break
        for k in bigger:
            servos[k] = LEADER_BIG_SERVO
    return ArmSpec(**{**lead.__dict__, "motors": tuple(servos)})


def write_arm(spec: ArmSpec, folder: Path) -> list[Path]:
    """Write NAME.xml, scenes/NAME_table.xml and the leader gello_NAME.xml (+ its scene) into `folder`."""
    from hardware.arms.generate import arm_xml, scene_xml

    (folder / "scenes").mkdir(parents=True, exist_ok=True)
    out = []
    for s in (spec, leader_spec(spec)):
        for path, text in ((folder / f"{s.name}.xml", arm_xml(s)),
                           (folder / "scenes" / f"{s.name}_table.xml", scene_xml(s))):
            path.write_text(text)
            out.append(path)
    return out


def sanitized_urdf(path: Path) -> str:
    """The URDF without meshes and joint dynamics (what pinocchio and MuJoCo compare on); continuous joints
    as revolute with +-CONTINUOUS_RANGE_RAD."""
    import xml.etree.ElementTree as ET

    root = ET.parse(path).getroot()
    for link in root.findall("link"):
        for tag in ("visual", "collision"):
            for el in link.findall(tag):
                link.remove(el)
    for j in root.findall("joint"):
        for el in j.findall("dynamics"):
            j.remove(el)
        if j.get("type") == "continuous":
            j.set("type", "revolute")
            lim = j.find("limit")
            if lim is None:
                lim = ET.SubElement(j, "limit", effort="1", velocity="1")
            lim.set("lower", str(-CONTINUOUS_RANGE_RAD))
            lim.set("upper", str(CONTINUOUS_RANGE_RAD))
    for el in root.findall("mujoco"):
        root.remove(el)
    ET.SubElement(ET.SubElement(root, "mujoco"), "compiler", discardvisual="true", fusestatic="true",
                  balanceinertia="false")
    return ET.tostring(root, encoding="unicode")


def agreement(path: Path, desc, n_samples: int = 20, seed: int = 0) -> dict[str, float]:
    """Largest relative difference [-] over random states between pinocchio on the URDF, MuJoCo on the URDF
    and the written description (pinocchio on its MJCF, armature taken out): gravity and inverse dynamics."""
    import mujoco
    import pinocchio as pin

    text = sanitized_urdf(path)
    try:
        pm = pin.buildModelFromXML(text)
    except Exception as exc:  # pinocchio raises plain RuntimeErrors with the parser's message
        raise UrdfError(f"pinocchio cannot read it: {str(exc).splitlines()[0]}", where=str(path),
                        fix="check the URDF against the URDF specification") from None
    try:
        mm = mujoco.MjModel.from_xml_string(text)
    except Exception as exc:
        raise UrdfError(f"MuJoCo cannot compile it: {str(exc).strip().splitlines()[0]}", where=str(path),
                        fix="check the inertials (MuJoCo refuses non-physical inertias)") from None
    dm = desc.pinocchio_model()
    n = dm.nv
    if pm.nv != n or mm.nv != n:
        raise UrdfError(f"{pm.nv} pinocchio / {mm.nv} MuJoCo / {n} description joints", where=str(path),
                        fix="import a serial arm without extra moving joints")
    pd, dd, md = pm.createData(), dm.createData(), mujoco.MjData(mm)
    dof = [int(mm.jnt_dofadr[mujoco.mj_name2id(mm, mujoco.mjtObj.mjOBJ_JOINT, jn)])
           for jn in desc.joint_names]
    rng = np.random.default_rng(seed)
    lim = desc.limits
    worst = {"gravity_pin_vs_mujoco": 0.0, "rnea_pin_vs_mujoco": 0.0, "gravity_urdf_vs_description": 0.0,
             "rnea_urdf_vs_description": 0.0}
    arm_a = np.asarray(dm.armature, float)
    for _ in range(n_samples):
        q = rng.uniform(np.maximum(lim.q_min, -math.pi), np.minimum(lim.q_max, math.pi))
        qd, qdd = rng.normal(size=n), rng.normal(size=n)
        g_p, t_p = pin.computeGeneralizedGravity(pm, pd, q).copy(), pin.rnea(pm, pd, q, qd, qdd).copy()
        g_d = pin.computeGeneralizedGravity(dm, dd, q).copy()
        t_d = pin.rnea(dm, dd, q, qd, qdd) - arm_a * qdd
        md.qpos[dof], md.qvel[:], md.qacc[:] = q, 0.0, 0.0
        mujoco.mj_inverse(mm, md)
        g_m = md.qfrc_inverse[dof].copy()
        md.qvel[dof], md.qacc[dof] = qd, qdd
        mujoco.mj_inverse(mm, md)
        t_m = md.qfrc_inverse[dof].copy()
        for key, a, b in (("gravity_pin_vs_mujoco", g_p, g_m), ("rnea_pin_vs_mujoco", t_p, t_m),
                          ("gravity_urdf_vs_description", g_p, g_d), ("rnea_urdf_vs_description", t_p, t_d)):
            worst[key] = max(worst[key], float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(a))))))
    return worst


def check_name(name: str) -> None:
    from hardware.arms import list_arms

    if not NAME_RE.match(name) or name.startswith("gello_"):
        raise UrdfError(f"arm name '{name}' not usable", where="--name",
                        fix="lower-case letters, digits and _, starting with a letter (not gello_...)")
    if name in list_arms():
        raise UrdfError(f"'{name}' is a built-in arm", where="--name", fix="pick another name")


__all__ = ["UrdfError", "agreement", "check", "check_name", "leader_spec", "sanitized_urdf", "to_spec",
           "user_arms_dir", "write_arm"]
