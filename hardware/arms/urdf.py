"""A vendor URDF as an arm description: read, check, convert (`factr2 arm import`, docs/arms_import.md).

read_urdf(path) -> UrdfArm: the serial chain of a URDF (xml.etree, no meshes needed). Defects that make the
file unusable raise UrdfError (one line: what, where, how to fix): a moving link without <inertial>, a
joint type this project cannot drive (prismatic, floating, planar), a <mimic> joint, a broken parent chain
(a joint naming an undeclared link, a link with two parents, no or several roots, a branch with moving
joints). Fixed joints are lumped into their moving parent (mass, centre of mass and inertia combined); the
deepest fixed frame after the last moving joint is the end effector.

to_spec(arm, name) -> hardware.arms.specs.ArmSpec: the same tables the built-in arms are generated from, so
hardware.arms.generate writes the MJCF (with the factr2.* fields the loader needs), its table scene and a
GELLO-style leader exactly as for a built-in arm. Units: m, kg, kg*m^2, rad, rad/s, N*m.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hardware.errors import ConfigError

DRIVEN = ("revolute", "continuous")
UNSUPPORTED = ("prismatic", "floating", "planar")
CONTINUOUS_RANGE_RAD = 2 * math.pi  # a continuous joint gets +-this range in the twin (a finding says so)


class UrdfError(ConfigError):
    """A URDF this project cannot use (the message names the element and the fix)."""


@dataclass
class Body:
    """Mass [kg], centre of mass [m] and inertia about it (3x3) [kg*m^2], in a link's frame."""

    mass: float = 0.0
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    def moved(self, pos: np.ndarray, rot: np.ndarray) -> Body:
        """The body expressed in a parent frame where this frame sits at (pos, rot)."""
        return Body(self.mass, pos + rot @ self.com, rot @ self.inertia @ rot.T)

    def __add__(self, other: Body) -> Body:
        m = self.mass + other.mass
        if m <= 0.0:
            return Body()
        c = (self.mass * self.com + other.mass * other.com) / m
        out = np.zeros((3, 3))
        for b in (self, other):
            d = b.com - c
            out += b.inertia + b.mass * (d @ d * np.eye(3) - np.outer(d, d))
        return Body(m, c, out)


@dataclass
class UrdfJoint:
    name: str
    kind: str
    parent: str
    child: str
    xyz: np.ndarray
    rpy: np.ndarray
    axis: np.ndarray
    lower: float | None = None  # rad
    upper: float | None = None
    effort: float | None = None  # N*m
    velocity: float | None = None  # rad/s
    damping: float = 0.0  # N*m*s/rad
    friction: float = 0.0  # N*m


@dataclass
class UrdfArm:
    """The moving joints in order, the body each one carries (fixed children lumped in), the base body, the
    end-effector frame in the last moving link (pos [m], rotation), total mass [kg] and findings (text)."""

    path: Path
    robot: str
    joints: list[UrdfJoint]
    bodies: list[Body]
    base: Body
    ee_pos: np.ndarray
    ee_rot: np.ndarray
    total_mass: float
    findings: list[str] = field(default_factory=list)


def rpy_matrix(rpy) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes x, then y, then z) -> rotation matrix."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _floats(el, attr: str, default: str, where: str) -> np.ndarray:
    text = el.get(attr, default) if el is not None else default
    try:
        return np.array([float(v) for v in text.split()])
    except ValueError:
        raise UrdfError(f"{attr}=\"{text}\" is not a list of numbers", where=where,
                        fix="write plain numbers (no expressions or xacro macros: run xacro first)") from None


def _opt(el, attr: str) -> float | None:
    if el is None or el.get(attr) is None:
        return None
    try:
        return float(el.get(attr))
    except ValueError:
        return None


def _inertial(link, where: str) -> Body | None:
    el = link.find("inertial")
    if el is None:
        return None
    org = el.find("origin")
    xyz, rpy = _floats(org, "xyz", "0 0 0", where), _floats(org, "rpy", "0 0 0", where)
    mass_el, i_el = el.find("mass"), el.find("inertia")
    mass = _opt(mass_el, "value")
    names = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
    vals = [_opt(i_el, k) for k in names]
    if mass is None or any(v is None for v in vals):
        raise UrdfError("<inertial> without <mass value> or a full <inertia ixx..izz>", where=where,
                        fix="give mass and all six inertia terms")
    ixx, iyy, izz, ixy, ixz, iyz = vals
    ten = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    rot = rpy_matrix(rpy)
    return Body(mass, xyz, rot @ ten @ rot.T)


def _joint(el, path: Path) -> UrdfJoint:
    name = el.get("name", "?")
    where = f"{path.name}: joint '{name}'"
    kind = el.get("type", "")
    if el.find("mimic") is not None:
        raise UrdfError("mimic joint (it follows another joint, no motor of its own)", where=where,
                        fix="make it fixed, or remove it (e.g. a gripper's mirror finger) before importing")
    if kind in UNSUPPORTED or kind not in DRIVEN + ("fixed",):
        raise UrdfError(f"joint type '{kind}' cannot be driven here (revolute, continuous or fixed only)",
                        where=where, fix="make it fixed, or cut the chain before it (e.g. a gripper)")
    parent, child = el.find("parent"), el.find("child")
    if parent is None or child is None or not parent.get("link") or not child.get("link"):
        raise UrdfError("joint without <parent link> or <child link>", where=where,
                        fix="name both links of every joint (broken parent chain)")
    org, lim, dyn = el.find("origin"), el.find("limit"), el.find("dynamics")
    axis = _floats(el.find("axis"), "xyz", "1 0 0", where)
    norm = float(np.linalg.norm(axis))
    if kind != "fixed" and not norm > 0:
        raise UrdfError("joint axis of zero length", where=where, fix="give a unit axis xyz")
    return UrdfJoint(name, kind, parent.get("link"), child.get("link"), _floats(org, "xyz", "0 0 0", where),
                     _floats(org, "rpy", "0 0 0", where), axis / (norm or 1.0), _opt(lim, "lower"),
                     _opt(lim, "upper"), _opt(lim, "effort"), _opt(lim, "velocity"),
                     _opt(dyn, "damping") or 0.0, _opt(dyn, "friction") or 0.0)


def read_urdf(path: str | Path) -> UrdfArm:
    """Parse and reduce a URDF to its serial chain (UrdfError on the defects in the module docstring)."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise UrdfError(f"cannot read the URDF ({exc})", where=str(path),
                        fix="give a readable URDF file") from None
    if root.tag != "robot":
        raise UrdfError(f"root element <{root.tag}>, expected <robot>", where=str(path),
                        fix="give a URDF file")
    links = {lk.get("name"): lk for lk in root.findall("link")}
    joints = [_joint(j, path) for j in root.findall("joint")]
    parent_of: dict[str, UrdfJoint] = {}
    for j in joints:
        for end in (j.parent, j.child):
            if end not in links:
                raise UrdfError(f"joint '{j.name}' names link '{end}', which is not declared (broken parent "
                                "chain)", where=str(path),
                                fix=f"declare <link name=\"{end}\"> or fix the name")
        if j.child in parent_of:
            raise UrdfError(f"link '{j.child}' has two parent joints "
                            f"('{parent_of[j.child].name}', '{j.name}')",
                            where=str(path), fix="each link has one parent joint (broken parent chain)")
        parent_of[j.child] = j
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        raise UrdfError(f"{len(roots)} root links ({', '.join(roots[:4]) or 'a cycle'}), expected one",
                        where=str(path), fix="connect every link to one base link (broken parent chain)")
    children: dict[str, list[UrdfJoint]] = {}
    for j in joints:
        children.setdefault(j.parent, []).append(j)
    arm = UrdfArm(path, root.get("name", path.stem), [], [], Body(), np.zeros(3), np.eye(3), 0.0)
    _walk(arm, links, children, roots[0])
    if not arm.joints:
        raise UrdfError("no revolute or continuous joint", where=str(path),
                        fix="give an arm with moving joints")
    return arm


def _subtree(links, children, name, pos, rot, where) -> tuple[Body, list[tuple[UrdfJoint, np.ndarray,
                                                                              np.ndarray]], tuple]:
    """Everything rigidly attached to link `name` (placed at pos, rot in the frame being built): the lumped
    body, the moving joints leaving it (with their parent frame) and the end-effector candidate: the deepest
    massless fixed frame (a tool flange), else the deepest fixed frame, as (rank, pos, rot)."""
    link_where = f"{where}: link '{name}'"
    body = _inertial(links[name], link_where)
    total = body.moved(pos, rot) if body is not None else Body()
    moving, best = [], ((body is None or body.mass == 0.0, 0), pos, rot)
    for j in children.get(name, []):
        if j.kind == "fixed":
            r2 = rot @ rpy_matrix(j.rpy)
            sub, mv, deep = _subtree(links, children, j.child, pos + rot @ j.xyz, r2, where)
            total = total + sub
            moving += mv
            rank = (deep[0][0], deep[0][1] + 1)
            if rank > best[0]:
                best = (rank, deep[1], deep[2])
        else:
            moving.append((j, pos, rot))
    return total, moving, best


def _walk(arm: UrdfArm, links, children, root: str) -> None:
    where = arm.path.name
    base, moving, _ = _subtree(links, children, root, np.zeros(3), np.eye(3), where)
    arm.base = base
    while moving:
        if len(moving) > 1:
            raise UrdfError(f"the chain branches into moving joints {[m[0].name for m in moving]}",
                            where=where,
                            fix="import a serial arm: fix or remove the side branch (e.g. fingers)")
        j, pos, rot = moving[0]
        if not np.allclose(pos, 0) or not np.allclose(rot, np.eye(3)):
            # a fixed link sits between two moving joints: fold its offset into this joint's origin
            j.xyz, j.rpy = pos + rot @ j.xyz, _matrix_rpy(rot @ rpy_matrix(j.rpy))
        if links[j.child].find("inertial") is None:
            raise UrdfError(f"moving link '{j.child}' (after joint '{j.name}') has no <inertial>",
                            where=where,
                            fix="add its <inertial> (mass, origin, inertia) from the vendor's CAD data")
        body, moving, deepest = _subtree(links, children, j.child, np.zeros(3), np.eye(3), where)
        arm.joints.append(j)
        arm.bodies.append(body)
        arm.ee_pos, arm.ee_rot = deepest[1], deepest[2]
    arm.total_mass = base.mass + sum(b.mass for b in arm.bodies)


def _matrix_rpy(r: np.ndarray) -> np.ndarray:
    """Inverse of rpy_matrix (roll, pitch, yaw) [rad]."""
    pitch = math.asin(max(-1.0, min(1.0, -r[2, 0])))
    if abs(math.cos(pitch)) > 1e-9:
        return np.array([math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])])
    return np.array([math.atan2(-r[1, 2], r[1, 1]), pitch, 0.0])


def matrix_quat(r: np.ndarray) -> tuple:
    """Rotation matrix -> (w, x, y, z) quaternion."""
    w = math.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    return (w, x, y, z)
