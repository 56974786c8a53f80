"""A URDF from an arm's tables (hardware/arms/specs.py): the built-in arms' URDF-equivalents.

    python -m hardware.arms.urdf_write piper > piper.urdf

Used to check `factr2 arm import` against the built-in descriptions (tests/test_arm_import.py): the import
of this file must give the same dynamics. Gripper fingers become fixed links at their closed position (the
description's pinocchio model locks them there); the end effector is a massless link "ee".
"""

from __future__ import annotations

import math
import sys

from hardware.arms.specs import ALL_SPECS, ArmSpec


def _f(x: float) -> str:
    return f"{float(x):.17g}"


def _v(t) -> str:
    return " ".join(_f(x) for x in t)


def quat_rpy(q: tuple) -> tuple:
    """(w, x, y, z) quaternion -> URDF roll-pitch-yaw [rad]."""
    norm = math.sqrt(sum(v * v for v in q))  # tables carry 8-digit quaternions: asin near 1 amplifies that
    w, x, y, z = (v / norm for v in q)
    sinp = max(-1.0, min(1.0, 2 * (w * y - z * x)))
    return (math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)), math.asin(sinp),
            math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def _inertial(mass, com, inertia) -> str:
    ixx, iyy, izz, ixy, ixz, iyz = inertia
    return (f'<inertial><origin xyz="{_v(com)}" rpy="0 0 0"/><mass value="{_f(mass)}"/>'
            f'<inertia ixx="{_f(ixx)}" iyy="{_f(iyy)}" izz="{_f(izz)}" ixy="{_f(ixy)}" ixz="{_f(ixz)}" '
            f'iyz="{_f(iyz)}"/></inertial>')


def _origin(pos, rpy=None, quat=None) -> str:
    r = rpy if rpy is not None else (quat_rpy(quat) if quat is not None else (0.0, 0.0, 0.0))
    return f'<origin xyz="{_v(pos)}" rpy="{_v(r)}"/>'


def spec_urdf(spec: ArmSpec) -> str:
    """The URDF text of an arm's tables (rigid-body data, limits, joint damping and friction)."""
    out = [f'<robot name="{spec.name}">',
           f'  <link name="base">{_inertial(spec.base_mass, spec.base_com, spec.base_inertia)}</link>']
    parent = "base"
    for lk in spec.links:
        child = f"{lk.name}_link"
        out.append(f'  <link name="{child}">{_inertial(lk.mass, lk.com, lk.inertia)}</link>')
        if lk.fixed:
            out.append(f'  <joint name="{lk.name}" type="fixed"><parent link="{parent}"/>'
                       f'<child link="{child}"/>'
                       f'{_origin(lk.pos, lk.rpy, lk.quat)}</joint>')
        else:
            out.append(f'  <joint name="{lk.name}" type="revolute"><parent link="{parent}"/>'
                       f'<child link="{child}"/>{_origin(lk.pos, lk.rpy, lk.quat)}<axis xyz="{_v(lk.axis)}"/>'
                       f'<limit lower="{_f(lk.range[0])}" upper="{_f(lk.range[1])}" '
                       f'effort="{_f(lk.tau_max)}" '
                       f'velocity="{_f(lk.v_max)}"/><dynamics damping="{_f(lk.damping)}" '
                       f'friction="{_f(lk.frictionloss)}"/></joint>')
        parent = child
    for fg in spec.fingers:
        out.append(f'  <link name="{fg.name}_link">{_inertial(fg.mass, fg.com, fg.inertia)}</link>')
        out.append(f'  <joint name="{fg.name}_fixed" type="fixed"><parent link="{parent}"/>'
                   f'<child link="{fg.name}_link"/>{_origin(fg.pos, None, fg.quat)}</joint>')
    out.append('  <link name="ee"/>')
    out.append(f'  <joint name="ee_fixed" type="fixed"><parent link="{parent}"/><child link="ee"/>'
               f'{_origin(spec.ee_pos, None, spec.ee_quat)}</joint>')
    out.append("</robot>")
    return "\n".join(out) + "\n"


def main(argv: list[str]) -> int:
    specs = {s.name: s for s in ALL_SPECS}
    if len(argv) != 1 or argv[0] not in specs:
        print(f"usage: python -m hardware.arms.urdf_write {{{','.join(specs)}}}", file=sys.stderr)
        return 2
    sys.stdout.write(spec_urdf(specs[argv[0]]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
