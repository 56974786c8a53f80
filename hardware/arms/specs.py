"""Numeric tables behind the arm MJCF files (the single source of their numbers; docs/arms.md cites them).

`python -m hardware.arms.generate` turns these tables into hardware/arms/*.xml and scenes/*_table.xml.
Units: m, kg, kg*m^2, rad, rad/s, N*m, N*m/s. Inertia tuples are (ixx, iyy, izz, ixy, ixz, iyz) about the
centre of mass, in the body frame. Body frames: `pos` in the parent frame, `rpy` (URDF convention:
fixed-axis roll-pitch-yaw) or `quat` (w x y z). The files carry quaternions only (pinocchio's MJCF reader
mishandles `euler`, so the generator converts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

DEG = math.pi / 180.0
# Torque-slew limit rule where no vendor figure exists: full torque in 50 ms (docs/arms.md).
TAU_RATE_RISE_S = 0.05


@dataclass(frozen=True)
class Geom:
    """Collision geometry (capsule: fromto + radius; box: pos + half sizes; sphere: pos + radius)."""

    kind: str
    size: tuple
    fromto: tuple | None = None
    pos: tuple | None = None


@dataclass(frozen=True)
class Link:
    name: str
    pos: tuple
    axis: tuple
    range: tuple  # rad
    mass: float
    com: tuple
    inertia: tuple
    tau_max: float  # N*m
    v_max: float  # rad/s
    armature: float  # kg*m^2 (reflected rotor inertia)
    damping: float = 0.0  # N*m*s/rad
    frictionloss: float = 0.0  # N*m
    tau_rate_max: float | None = None  # N*m/s, None: tau_max / TAU_RATE_RISE_S
    rpy: tuple | None = None
    quat: tuple | None = None
    geoms: tuple = ()
    fixed: bool = False  # a rigid child without a joint (e.g. a hand flange)


@dataclass(frozen=True)
class Finger:
    """One gripper DOF: a slide finger (m) or a leader trigger hinge (rad)."""

    name: str
    pos: tuple
    axis: tuple
    range: tuple
    mass: float
    com: tuple
    inertia: tuple
    kind: str = "slide"
    geoms: tuple = ()
    quat: tuple | None = None


@dataclass(frozen=True)
class ArmSpec:
    name: str
    role: str  # "follower" | "leader" | "sim"
    title: str
    base_mass: float
    base_com: tuple
    base_inertia: tuple
    base_geoms: tuple
    links: tuple
    ee_pos: tuple  # end-effector site in the last link frame
    fingers: tuple = ()  # first finger is the actuated one; the second mirrors it (equality)
    gripper_force: float = 10.0  # N, position actuator force limit
    q_home: tuple = ()
    rgba: str = "0.75 0.75 0.78 1"
    notes: str = ""
    ee_quat: tuple = (1.0, 0.0, 0.0, 0.0)
    extra_bodies: tuple = field(default_factory=tuple)
    motors: tuple = ()  # twin motor presets per joint (hardware.sim.presets), written as factr2.motors


def _scaled(inertia: tuple, k: float) -> tuple:
    return tuple(v * k for v in inertia)


def _cap(a: tuple, b: tuple, r: float) -> Geom:
    return Geom("capsule", (r,), fromto=a + b)


def _box(pos: tuple, half: tuple) -> Geom:
    return Geom("box", half, pos=pos)


def _box_inertia(m: float, half: tuple) -> tuple:
    a, b, c = (2 * h for h in half)
    return (m / 12 * (b * b + c * c), m / 12 * (a * a + c * c), m / 12 * (a * a + b * b), 0.0, 0.0, 0.0)


# --------------------------------------------------------------------------------------------------
# AgileX Piper. Kinematics (joint frames, axes) from AgileX's published piper_description URDF.
# Masses: the URDF's CAD masses add up to 1.15 kg while AgileX specifies 4.2 kg for the arm, so the
# link masses here are re-estimated to that total (motors sit in links 1-3); COMs are the CAD ones,
# inertias are the CAD tensors scaled by the mass ratio. Joint limits: AgileX SDK (hardware-protocols.md).
# v_max: AgileX spec sheet joint speeds (180/195/180/225/225/225 deg/s). tau_max, armature, friction:
# project estimates (no vendor figure), see docs/arms.md.
_PIPER_V = (180 * DEG, 195 * DEG, 180 * DEG, 225 * DEG, 225 * DEG, 225 * DEG)
PIPER = ArmSpec(
    name="piper", role="follower", title="AgileX Piper (6 DOF + parallel gripper)",
    base_mass=0.50, base_com=(-0.0098, 0.0, 0.041),
    base_inertia=_scaled((2.266e-4, 2.694e-4, 2.223e-4, -7.3e-8, 2.1e-6, 0.0), 3.08),
    base_geoms=(_cap((0, 0, 0.045), (0, 0, 0.085), 0.045),),
    links=(
        Link("joint1", pos=(0, 0, 0.123), rpy=(0, 0, -1.5708), axis=(0, 0, 1), range=(-150 * DEG, 150 * DEG),
             mass=0.71, com=(0.0013, 0.0003, -0.0092),
             inertia=_scaled((7.767e-5, 9.250e-5, 8.246e-5, 1.1e-7, -1.97e-6, 9.9e-7), 7.25),
             tau_max=25.0, v_max=_PIPER_V[0], armature=0.03, damping=0.1, frictionloss=0.3,
             geoms=(_cap((0, 0, -0.04), (0, 0, 0.0), 0.045),)),
        Link("joint2", pos=(0, 0, 0), rpy=(1.5708, -0.10095, -1.5708), axis=(0, 0, 1), range=(0.0, 180 * DEG),
             mass=1.17, com=(0.1476, -0.0174, 0.0018),
             inertia=_scaled((1.501e-4, 1.7259e-3, 1.7745e-3, 8.59e-5, -1.07e-6, -9.9e-7), 4.04),
             tau_max=25.0, v_max=_PIPER_V[1], armature=0.03, damping=0.1, frictionloss=0.3,
             geoms=(_cap((0.03, 0, 0), (0.26, 0, 0), 0.035),)),
        Link("joint3", pos=(0.28503, 0, 0), rpy=(0, 0, 1.3826), axis=(0, 0, 1), range=(-170 * DEG, 0.0),
             mass=0.50, com=(0.0157, 0.1045, 0.0005),
             inertia=_scaled((2.217e-4, 1.009e-4, 2.418e-4, -7.6e-6, -6.4e-7, -8.2e-7), 1.72),
             tau_max=25.0, v_max=_PIPER_V[2], armature=0.03, damping=0.1, frictionloss=0.3,
             geoms=(_cap((0.003, 0.04, 0), (0.02, 0.22, 0), 0.03),)),
        Link("joint4", pos=(0.021984, 0.25075, 0), rpy=(-1.5708, 0, 0), axis=(0, 0, -1),
             range=(-100 * DEG, 100 * DEG), mass=0.38, com=(0.0003, -0.0010, -0.0047),
             inertia=_scaled((3.820e-5, 4.870e-5, 4.106e-5, -4.9e-8, 4.9e-8, 6.7e-8), 2.99),
             tau_max=8.0, v_max=_PIPER_V[3], armature=0.003, damping=0.05, frictionloss=0.1,
             geoms=(_cap((0, 0, -0.02), (0, 0, 0.02), 0.03),)),
        Link("joint5", pos=(0, 0, 0), rpy=(1.5708, -0.087266, 0), axis=(0, 0, 1), range=(-70 * DEG, 70 * DEG),
             mass=0.38, com=(0.0001, 0.0567, -0.0020),
             inertia=_scaled((4.396e-5, 5.632e-5, 4.887e-5, -3.6e-8, -1.9e-8, -2.2e-7), 2.63),
             tau_max=8.0, v_max=_PIPER_V[4], armature=0.003, damping=0.05, frictionloss=0.1,
             geoms=(_cap((0, 0.03, 0), (0, 0.07, 0), 0.03),)),
        Link("joint6", pos=(0, 0.091, 0.0014165), rpy=(-1.5708, -1.5708, 0), axis=(0, 0, -1),
             range=(-120 * DEG, 120 * DEG), mass=0.45, com=(0.0, 0.0, 0.045),
             inertia=_box_inertia(0.45, (0.04, 0.03, 0.045)),
             tau_max=8.0, v_max=_PIPER_V[5], armature=0.003, damping=0.05, frictionloss=0.1,
             geoms=(_box((0, 0, 0.05), (0.04, 0.03, 0.035)),)),
    ),
    ee_pos=(0, 0, 0.135),
    fingers=(
        Finger("gripper", pos=(0, 0, 0.085), axis=(1, 0, 0), range=(0.0, 0.035), mass=0.025,
               com=(0.006, 0, 0.03), inertia=_box_inertia(0.025, (0.006, 0.01, 0.03)),
               geoms=(_box((0.006, 0, 0.03), (0.006, 0.01, 0.03)),)),
        Finger("gripper_mirror", pos=(0, 0, 0.085), axis=(-1, 0, 0), range=(0.0, 0.035), mass=0.025,
               com=(-0.006, 0, 0.03), inertia=_box_inertia(0.025, (0.006, 0.01, 0.03)),
               geoms=(_box((-0.006, 0, 0.03), (0.006, 0.01, 0.03)),)),
    ),
    gripper_force=10.0,
    q_home=(0.0, 1.2, -1.0, 0.0, 0.6, 0.0),
    rgba="0.80 0.82 0.86 1",
)

# --------------------------------------------------------------------------------------------------
# I2RT YAM. Kinematics, masses, COMs and inertias from I2RT's published yam.xml / linear_4310.xml,
# re-expressed in world-aligned frames at q = 0 (every body frame parallel to the world at the zero pose).
# Motors: DM4340 on J1-J3, DM4310 on J4-J6 (tau_max = motor peak 27 / 7 N*m, armature 0.032 / 0.0018
# from I2RT). v_max: DM4340 VMAX register 8 rad/s; DM4310 ~20 rad/s (200 rpm no-load, below VMAX 30).
_DM4340 = dict(tau_max=27.0, v_max=8.0, armature=0.032, damping=0.1, frictionloss=0.25)
_DM4310 = dict(tau_max=7.0, v_max=20.0, armature=0.0018, damping=0.02, frictionloss=0.05)
# World positions at q = 0: joint anchors, link COMs; inertia tensors in the world frame.
YAM = ArmSpec(
    name="yam", role="follower", title="I2RT YAM (6 DOF, DM4340/DM4310, linear gripper)",
    base_mass=0.8737, base_com=(0.0, 0.0, 0.0248), base_inertia=(1.69e-3, 6.78e-4, 1.571e-3, 0, 0, 0),
    base_geoms=(_cap((0, 0, 0.03), (0, 0, 0.05), 0.045),),
    links=(
        Link("joint1", pos=(0, 0, 0.068), axis=(0, 0, 1), range=(-2.618, 3.1416), mass=0.1012,
             com=(0.0073, 0.0017, 0.0234), inertia=(1.32e-4, 5.0e-5, 1.07e-4, -2e-6, -6e-6, -1e-6),
             geoms=(_cap((0, 0, 0.0), (0, 0, 0.03), 0.04),), **_DM4340),
        Link("joint2", pos=(0.02, 0.0339, 0.0455), axis=(0, 1, 0), range=(0.0, 3.6652), mass=1.4691,
             com=(-0.1292, -0.0331, 0.0001), inertia=(8.0e-4, 1.460e-2, 1.4669e-2, 0, 0, 0),
             geoms=(_cap((-0.02, -0.034, 0), (-0.244, -0.034, 0), 0.035),), **_DM4340),
        Link("joint3", pos=(-0.264, -0.0688, 0.0), axis=(0, -1, 0), range=(0.0, 3.1416), mass=0.9826,
             com=(0.1351, 0.0341, 0.0556), inertia=(9.4e-4, 7.63e-3, 7.59e-3, -1e-5, -6.4e-4, 0),
             geoms=(_cap((0.02, 0.035, 0.01), (0.225, 0.035, 0.055), 0.03),), **_DM4340),
        Link("joint4", pos=(0.245, 0.0688, 0.06), axis=(0, -1, 0), range=(-1.693, 1.5708), mass=0.4622,
             com=(0.0576, -0.0327, 0.0551), inertia=(6.0e-4, 7.6e-4, 4.7e-4, 3e-5, -2.4e-4, 3e-5),
             geoms=(_cap((0.0, -0.034, 0.0), (0.06, -0.034, 0.045), 0.03),), **_DM4310),
        Link("joint5", pos=(0.074, -0.0339, 0.0405), axis=(0, 0, -1), range=(-1.5708, 1.5708), mass=0.4033,
             com=(0.0008, 0.0, -0.0376), inertia=(1.8e-4, 2.2e-4, 1.8e-4, 0, 1e-5, 0),
             geoms=(_cap((0.0, 0.0, -0.01), (0.03, 0.0, -0.04), 0.028),), **_DM4310),
        Link("joint6", pos=(0.0356, 0.0, -0.0405), axis=(1, 0, 0), range=(-2.0944, 2.0944), mass=0.5532,
             com=(0.0293, -0.0002, 0.0), inertia=(3.7e-4, 3.2e-4, 4.1e-4, 0, 0, 0),
             geoms=(_box((0.035, 0, 0), (0.035, 0.045, 0.03)),), **_DM4310),
    ),
    ee_pos=(0.14, 0, 0), ee_quat=(0.70710678, 0.0, 0.70710678, 0.0),
    fingers=(
        Finger("gripper", pos=(0.0545, 0.0, 0.0), axis=(0, -1, 0), range=(0.0, 0.0475), mass=0.0710,
               com=(0.022, -0.012, 0.0), inertia=(5e-5, 5e-5, 5e-5, 0, 0, 0),
               geoms=(_box((0.045, -0.012, 0), (0.045, 0.006, 0.012)),)),
        Finger("gripper_mirror", pos=(0.0545, 0.0, 0.0), axis=(0, 1, 0), range=(0.0, 0.0475), mass=0.0710,
               com=(0.022, 0.012, 0.0), inertia=(5e-5, 5e-5, 5e-5, 0, 0, 0),
               geoms=(_box((0.045, 0.012, 0), (0.045, 0.006, 0.012)),)),
    ),
    gripper_force=30.0,
    q_home=(0.0, 1.0, 1.0, 0.0, 0.0, 0.0),
    rgba="0.35 0.22 0.55 1",
)

# --------------------------------------------------------------------------------------------------
# Franka Emika Panda (simulation only). Kinematics: Franka's published (Craig) DH table. Inertials:
# franka_ros `inertial.yaml` (identified values of Gaz et al. 2019, as franka_ros publishes them).
# Limits: Franka's published joint ranges, 2.175/2.61 rad/s, 87/12 N*m, 1000 N*m/s torque derivative.
_RX_P = (0.70710678, 0.70710678, 0.0, 0.0)  # +90 deg about x
_RX_M = (0.70710678, -0.70710678, 0.0, 0.0)  # -90 deg about x
_BIG = dict(tau_max=87.0, v_max=2.175, armature=0.1, damping=0.1, tau_rate_max=1000.0)
_SMALL = dict(tau_max=12.0, v_max=2.61, armature=0.1, damping=0.1, tau_rate_max=1000.0)
PANDA = ArmSpec(
    name="panda", role="sim", title="Franka Emika Panda (7 DOF + hand), simulation only",
    base_mass=0.629769, base_com=(-0.041018, -0.00014, 0.049974),
    base_inertia=(0.00315, 0.00388, 0.004285, 8.2904e-07, 0.00015, 8.2299e-06),
    base_geoms=(_cap((-0.03, 0, 0.04), (0, 0, 0.12), 0.07),),
    links=(
        Link("joint1", pos=(0, 0, 0.333), axis=(0, 0, 1), range=(-2.8973, 2.8973), mass=4.970684,
             com=(0.003875, 0.002081, -0.04762),
             inertia=(0.70337, 0.70661, 0.009117, -0.000139, 0.006772, 0.019169),
             geoms=(_cap((0, 0, -0.19), (0, 0, -0.04), 0.06),), **_BIG),
        Link("joint2", pos=(0, 0, 0), quat=_RX_M, axis=(0, 0, 1), range=(-1.7628, 1.7628), mass=0.646926,
             com=(-0.003141, -0.02872, 0.003495),
             inertia=(0.007962, 0.02811, 0.025995, -0.003925, 0.010254, 0.000704),
             geoms=(_cap((0, -0.03, 0), (0, -0.2, 0), 0.06),), **_BIG),
        Link("joint3", pos=(0, -0.316, 0), quat=_RX_P, axis=(0, 0, 1), range=(-2.8973, 2.8973), mass=3.228604,
             com=(0.027518, 0.039252, -0.066502),
             inertia=(0.037242, 0.036155, 0.01083, -0.004761, -0.011396, -0.012805),
             geoms=(_cap((0, 0, -0.15), (0.06, 0, -0.01), 0.06),), **_BIG),
        Link("joint4", pos=(0.0825, 0, 0), quat=_RX_P, axis=(0, 0, 1), range=(-3.0718, -0.0698),
             mass=3.587895, com=(-0.05317, 0.104419, 0.027454),
             inertia=(0.025853, 0.019552, 0.028323, 0.007796, -0.001332, 0.008641),
             geoms=(_cap((0, 0, 0), (-0.08, 0.11, 0), 0.06),), **_BIG),
        Link("joint5", pos=(-0.0825, 0.384, 0), quat=_RX_M, axis=(0, 0, 1), range=(-2.8973, 2.8973),
             mass=1.225946, com=(-0.011953, 0.041065, -0.038437),
             inertia=(0.035549, 0.029474, 0.008627, -0.002117, -0.004037, 0.000229),
             geoms=(_cap((0, 0, -0.25), (0, 0.0, -0.04), 0.055),), **_SMALL),
        Link("joint6", pos=(0, 0, 0), quat=_RX_P, axis=(0, 0, 1), range=(-0.0175, 3.7525), mass=1.666555,
             com=(0.060149, -0.014117, -0.010517),
             inertia=(0.001964, 0.004354, 0.005433, 0.000109, -0.001158, 0.000341),
             geoms=(_cap((0, 0, -0.03), (0.088, 0, 0), 0.05),), **_SMALL),
        Link("joint7", pos=(0.088, 0, 0), quat=_RX_P, axis=(0, 0, 1), range=(-2.8973, 2.8973), mass=0.735522,
             com=(0.010517, -0.004252, 0.061597),
             inertia=(0.012516, 0.010027, 0.004815, -0.000428, -0.001196, -0.000741),
             geoms=(_cap((0, 0, -0.03), (0, 0, 0.07), 0.04),), **_SMALL),
        # The hand: rigid on the flange (0.107 m), turned -45 deg about z as on the real arm.
        Link("hand", pos=(0, 0, 0.107), quat=(0.92387953, 0.0, 0.0, -0.38268343), axis=(0, 0, 1),
             range=(0, 0), mass=0.73, com=(-0.01, 0, 0.03), inertia=(0.001, 0.0025, 0.0017, 0, 0, 0),
             geoms=(_box((0, 0, 0.03), (0.025, 0.09, 0.025)),), fixed=True,
             tau_max=1.0, v_max=1.0, armature=0.0),
    ),
    ee_pos=(0, 0, 0.1034),
    fingers=(
        Finger("gripper", pos=(0, 0, 0.0584), axis=(0, 1, 0), range=(0.0, 0.04), mass=0.015,
               com=(0, 0.01, 0.025), inertia=(2.375e-06, 2.375e-06, 7.5e-07, 0, 0, 0),
               geoms=(_box((0, 0.008, 0.025), (0.01, 0.008, 0.025)),)),
        Finger("gripper_mirror", pos=(0, 0, 0.0584), axis=(0, -1, 0), range=(0.0, 0.04), mass=0.015,
               com=(0, -0.01, 0.025), inertia=(2.375e-06, 2.375e-06, 7.5e-07, 0, 0, 0),
               geoms=(_box((0, -0.008, 0.025), (0.01, 0.008, 0.025)),)),
    ),
    gripper_force=70.0,
    q_home=(0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785),
    rgba="0.92 0.92 0.92 1",
)

# --------------------------------------------------------------------------------------------------
# GELLO-style leaders: the follower's joint layout (same frames, axes, ranges) built from Dynamixel
# servos and 3D-printed links. Servo masses: XC330 23 g, XL330 18 g (ROBOTIS e-manual). Printed links:
# 6 g + 60 g/m along each segment (PLA at GELLO-like wall thickness), plus a 20 g handle at the tool.
# tau_max below stall torque (XC330-M288 0.93 N*m, XL330-M288 0.52 N*m); armature: reflected rotor
# inertia estimates for 288:1 gearing (project estimate).
SERVOS = {
    "XC330-M288": dict(mass=0.023, tau_max=0.9, v_max=8.0, armature=1.5e-4),
    "XL330-M288": dict(mass=0.018, tau_max=0.5, v_max=10.0, armature=1.0e-4),
    # XM430-W350 (82 g, stall 4.1 N*m at 12 V, 46 rpm no-load): for the leader of a big arm (UR5 reach)
    "XM430-W350": dict(mass=0.082, tau_max=3.5, v_max=4.8, armature=3.0e-4),
}
_PRINT_BASE_KG, _PRINT_KG_PER_M, _HANDLE_KG, _SERVO_CUBE_M = 0.006, 0.06, 0.020, 0.024


def _rotate(q: tuple, v: tuple) -> tuple:
    w, x, y, z = q
    r = ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
         (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
         (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))
    return tuple(sum(r[i][j] * v[j] for j in range(3)) for i in range(3))


def _lumped(parts: list[tuple[float, tuple, tuple]]) -> tuple[float, tuple, tuple]:
    """Combine (mass, com, inertia about own com) parts into one rigid body (mass, com, inertia)."""
    m = sum(p[0] for p in parts)
    c = tuple(sum(p[0] * p[1][i] for p in parts) / m for i in range(3))
    acc = [[0.0] * 3 for _ in range(3)]
    for mi, ci, (ixx, iyy, izz, ixy, ixz, iyz) in parts:
        own = ((ixx, ixy, ixz), (ixy, iyy, iyz), (ixz, iyz, izz))
        d = tuple(ci[i] - c[i] for i in range(3))
        dd = sum(v * v for v in d)
        for i in range(3):
            for j in range(3):
                acc[i][j] += own[i][j] + mi * ((dd if i == j else 0.0) - d[i] * d[j])
    return m, c, (acc[0][0], acc[1][1], acc[2][2], acc[0][1], acc[0][2], acc[1][2])


def _rod(m: float, a: tuple, b: tuple) -> tuple[float, tuple, tuple]:
    v = tuple(b[i] - a[i] for i in range(3))
    length2 = sum(x * x for x in v) or 1e-12
    k = m / 12.0
    inertia = (k * (length2 - v[0] ** 2), k * (length2 - v[1] ** 2), k * (length2 - v[2] ** 2),
               -k * v[0] * v[1], -k * v[0] * v[2], -k * v[1] * v[2])
    # a thin rod has zero inertia about its axis: add a 1 cm radius so the tensor stays positive definite
    r2 = 0.01 ** 2 * m / 2
    inertia = (inertia[0] + r2, inertia[1] + r2, inertia[2] + r2) + inertia[3:]
    return m, tuple((a[i] + b[i]) / 2 for i in range(3)), inertia


def _cube(m: float, c: tuple) -> tuple[float, tuple, tuple]:
    i = m * _SERVO_CUBE_M ** 2 / 6
    return m, c, (i, i, i, 0.0, 0.0, 0.0)


def gello_from(follower: ArmSpec, name: str, servos: tuple, trigger: Finger) -> ArmSpec:
    """A 1:1 GELLO-style leader of `follower`: same joints, servo + printed-link inertials."""
    links = []
    arm = [lk for lk in follower.links if not lk.fixed]
    for i, lk in enumerate(arm):
        s = SERVOS[servos[i]]
        if i + 1 < len(arm):
            nxt = arm[i + 1]
            end = nxt.pos  # next joint origin in this link's frame
            tail = _cube(SERVOS[servos[i + 1]]["mass"], end)
        else:
            end = follower.ee_pos
            tail = _cube(_HANDLE_KG, tuple(v / 2 for v in end))
        seg = math.sqrt(sum(v * v for v in end))
        rod = _rod(_PRINT_BASE_KG + _PRINT_KG_PER_M * seg, (0.0, 0.0, 0.0), end)
        m, c, inertia = _lumped([rod, tail])
        geoms = ((_cap((0.0, 0.0, 0.0), end, 0.015),) if seg > 0.02
                 else (Geom("sphere", (0.018,), pos=(0, 0, 0)),))
        links.append(Link(lk.name, pos=lk.pos, rpy=lk.rpy, quat=lk.quat, axis=lk.axis, range=lk.range,
                          mass=m, com=c, inertia=inertia, tau_max=s["tau_max"], v_max=s["v_max"],
                          armature=s["armature"], damping=0.005, frictionloss=0.01, geoms=geoms))
    base_m, base_c, base_i = _lumped([_cube(0.15, (0.0, 0.0, 0.02)),
                                      _cube(SERVOS[servos[0]]["mass"], arm[0].pos)])
    return ArmSpec(name=name, role="leader", title=f"GELLO-style Dynamixel leader for the {follower.name}",
                   base_mass=base_m, base_com=base_c, base_inertia=base_i,
                   base_geoms=(Geom("box", (0.04, 0.04, 0.02), pos=(0, 0, 0.02)),), links=tuple(links),
                   ee_pos=follower.ee_pos, ee_quat=follower.ee_quat, fingers=(trigger,), gripper_force=0.3,
                   q_home=follower.q_home, rgba="0.95 0.95 0.95 1")


GELLO_PIPER = gello_from(
    PIPER, "gello_piper", ("XC330-M288",) * 3 + ("XL330-M288",) * 3,
    Finger("trigger", kind="hinge", pos=(0, 0.03, 0.06), axis=(1, 0, 0), range=(0.0, 0.8), mass=0.010,
           com=(0, 0.0, 0.03), inertia=_box_inertia(0.010, (0.005, 0.008, 0.03)),
           geoms=(_box((0, 0, 0.03), (0.005, 0.008, 0.03)),)))
GELLO_YAM = gello_from(
    YAM, "gello_yam", ("XC330-M288",) * 3 + ("XL330-M288",) * 3,
    Finger("trigger", kind="hinge", pos=(0.06, 0.0, -0.03), axis=(0, 1, 0), range=(0.0, 0.8), mass=0.010,
           com=(0.03, 0.0, 0.0), inertia=_box_inertia(0.010, (0.03, 0.008, 0.005)),
           geoms=(_box((0.03, 0, 0), (0.03, 0.008, 0.005)),)))

ALL_SPECS = (PIPER, YAM, PANDA, GELLO_PIPER, GELLO_YAM)
