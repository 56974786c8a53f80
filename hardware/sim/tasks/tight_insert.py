"""tight-insert (SIMULATED): pick a headed round pin and insert it into a bore whose clearance (0.4 mm on the
diameter, 0.2 mm per side) is far below what a camera-based pose estimate can resolve (millimetres), so the
hole is found by feel: a search with light downward force until the pin drops. Stages: grasp, align, engage,
seat.

The pin: a square head (held by the fingers; box faces give the grasp a stable, multi-point contact) on a
round shaft. Its body frame sits at the shaft's tip, +z along the pin toward the head. The fixture: a ring of
N_SIDES wall segments around a through bore (MuJoCo primitives have no holes; the flats are the bore, their
corners lie CORNER_GAP_M further out), a 45 deg chamfer of CHAMFER_M at the mouth; the table is the bore's
floor. The pin is seated when its tip rests on the bore's floor (the shaft is longer than the bore, the head
stays clear of the fixture), which is also where a hand pushing down feels it stop. Poses drawn per
episode from the seed.

Detectors are pure functions of observe()'s arrays and judge from the twin's TRUTH (PRIVILEGED);
detectables() gives only what a pose estimator could report: the pin's and the fixture's poses.
"""

from __future__ import annotations

import numpy as np

from hardware.sim.tasks import base as B

SHAFT_R_M = 0.006  # m: 12 mm pin
SHAFT_L_M = 0.026  # m: shaft length below the head (longer than the bore: the pin bottoms on the table)
HEAD_HALF = (0.009, 0.009, 0.012)  # m: 18 x 18 x 24 mm square head (the fingers hold it)
PIN_MASS_KG = 0.085  # a steel pin of this size (shaft 23 g, head 62 g)
CLEARANCE_M = 0.0004  # m: bore diameter - pin diameter (0.2 mm per side)
BORE_R_M = SHAFT_R_M + CLEARANCE_M / 2  # m: distance of the bore's flats from its axis
CHAMFER_M = 0.002  # m: 45 deg lead-in at the mouth (what catches a pin this close to the axis); 2 mm, not
# 1: a search by pecks on a grid covers the disc in (2.2 / 1.2)^2 = 3.4x fewer pecks
CAPTURE_M = CLEARANCE_M / 2 + CHAMFER_M  # m: a pin tip this close to the axis slides in when pushed
DEPTH_M = 0.020  # m: fixture height = bore depth (through: the table is its floor)
FIXTURE_R_M = 0.024  # m: outer radius of the ring
N_SIDES = 32  # wall segments of the bore (16 made the shaft chatter between two flats when pushed sideways)
CORNER_GAP_M = BORE_R_M * (1 / np.cos(np.pi / N_SIDES) - 1)  # m: a corner's extra room over a flat (0.12 mm)
RAMP_THICK_M = 0.003  # m: thickness of each chamfer slab
SHAFT_FRICTION = 0.3  # shaft and fixture: lubricated steel on steel, so the search slides, not sticks
FIXTURE_FRICTION = 0.3  # (MuJoCo takes the larger of two geoms' values)
HEAD_FRICTION = 2.0  # knurled head: MuJoCo's soft friction creeps, and at the fingers' 1.0 a 3-5 N push (the
# search's) slid the pin up in the grasp at ~2 mm/s
IMPRATIO = 10.0  # the task scene's friction-to-normal impedance ratio (MuJoCo's advice for grasping with
# elliptic cones: it makes friction harder, so a held object creeps less); the default 1 let the pin creep
FINGERS = ("gripper_body", "gripper_mirror_body")
LIFT_M = 0.01  # grasp: tip this far above the table, held by both fingers
ALIGN_ABOVE_M = 0.003  # align: tip within CAPTURE_M of the axis and at most this far above the fixture top
ALIGN_TILT_RAD = np.deg2rad(3.0)
ENGAGE_BELOW_M = 0.001  # engage: tip this far below the chamfer's lower edge (in the straight bore)
INSIDE_TOL_M = 0.0001  # m: contact interpenetration allowed on top of the clearance (measured <= 0.05 mm)
SEAT_TOL_M = 0.0005  # seat: tip within this of the bore's floor (the table)
SEAT_TILT_RAD = np.deg2rad(2.0)
SEATED_TIP_Z_M = 0.0  # m: tip height when seated (on the table, the bore's floor)
# Episode ranges (world frame, m / rad); the Piper base is at the origin, the table top at z = 0.
PIN_X, PIN_Y, PIN_YAW = (0.24, 0.30), (-0.15, -0.09), (-0.35, 0.35)
HOLE_X, HOLE_Y, HOLE_YAW = (0.26, 0.32), (0.08, 0.14), (-0.35, 0.35)


def pin_metrics(pin_pos, pin_rot, hole_pos) -> dict:
    """Pure geometry: the tip's offset from the bore axis [m] (2, world xy) and its distance [m], tilt of the
    pin [rad], tip height above the table [m]."""
    tip, R = np.asarray(pin_pos, float), np.asarray(pin_rot, float)
    d = tip[:2] - np.asarray(hole_pos, float)[:2]
    return {"lateral_m": d, "radial_m": float(np.hypot(*d)),
            "tilt_rad": float(np.arccos(np.clip(R[2, 2], -1.0, 1.0))), "tip_z_m": float(tip[2])}


def detect_tight(obs: dict) -> np.ndarray:
    """[grasp, align, engage, seat] from observe()'s arrays (pure, the twin's truth)."""
    m = pin_metrics(obs["pin_pos"], obs["pin_rot"], obs["hole_pos"])
    grasp = bool(np.all(obs["finger_touch"])) and m["tip_z_m"] > LIFT_M
    align = (m["radial_m"] <= CAPTURE_M and m["tilt_rad"] <= ALIGN_TILT_RAD
             and m["tip_z_m"] <= DEPTH_M + ALIGN_ABOVE_M)
    inside = m["radial_m"] <= CLEARANCE_M / 2 + CORNER_GAP_M + INSIDE_TOL_M
    engage = inside and m["tip_z_m"] <= DEPTH_M - CHAMFER_M - ENGAGE_BELOW_M
    seat = inside and m["tip_z_m"] <= SEATED_TIP_Z_M + SEAT_TOL_M and m["tilt_rad"] <= SEAT_TILT_RAD
    return np.array([grasp, align, engage, seat])


def add_fixture(spec, name: str = "fixture") -> None:
    """The ring fixture (a mocap body: placed per episode) with its chamfered bore, built from boxes."""
    fix = spec.worldbody.add_body(name=name, pos=[0.29, 0.11, 0.0], mocap=True)
    r, c, ro = BORE_R_M, CHAMFER_M, FIXTURE_R_M
    w = ro * np.tan(np.pi / N_SIDES) + 0.0005  # tangential half width: neighbours overlap outside the bore
    lo = (DEPTH_M - c) / 2  # half height of the wall below the chamfer
    t = (ro - r) / 2
    tc = (ro - r - c) / 2
    r2 = np.sqrt(0.5)
    grey = (0.35, 0.38, 0.45, 1)
    for k in range(N_SIDES):  # segment k's bore face is normal to its +y, at distance r
        ang = 2 * np.pi * k / N_SIDES
        side = fix.add_body(name=f"{name}_side{k}", quat=[np.cos(ang / 2), 0, 0, np.sin(ang / 2)])
        kw = {"rgba": grey, "friction": (FIXTURE_FRICTION, 0.005, 0.0001)}
        B.add_box(side, f"{name}_wall{k}", (w, t, lo), pos=(0, r + t, lo), **kw)
        B.add_box(side, f"{name}_rim{k}", (w, tc, c / 2), pos=(0, r + c + tc, DEPTH_M - c / 2), **kw)
        ramp = B.add_box(side, f"{name}_chamfer{k}", (w, c / r2 / 2, RAMP_THICK_M / 2),
                         pos=(0, r + c / 2 + RAMP_THICK_M / 2 * r2, DEPTH_M - c / 2 - RAMP_THICK_M / 2 * r2),
                         **kw)
        ramp.quat = [np.cos(np.pi / 8), np.sin(np.pi / 8), 0, 0]  # 45 deg about the tangent: the lead-in


class TightInsert(B.Task):
    name = "tight-insert"
    title = "pick a 12 mm headed pin and insert it into a bore with 0.4 mm clearance (found by feel)"
    stages = ("grasp", "align", "engage", "seat")
    arms = ("piper",)
    episode_s = 60.0
    operator_perception = True  # its demonstrator is built to see through the detector (factr2_teleop/tasks/
    # tight.py reads only op.p.seen, never the truth); `factr2 collect` uses the detector by default

    def add_objects(self, spec, arm) -> None:
        import mujoco

        pin = spec.worldbody.add_body(name="pin", pos=[0.27, -0.12, 0.0])
        pin.add_freejoint(name="pin")
        orange = (0.95, 0.55, 0.1, 1)
        shaft = pin.add_geom(name="pin_shaft", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                             size=[SHAFT_R_M, SHAFT_L_M / 2, 0], pos=[0, 0, SHAFT_L_M / 2], rgba=list(orange),
                             friction=[SHAFT_FRICTION, 0.005, 0.0001], solref=list(B.SOLREF),
                             solimp=list(B.SOLIMP), margin=B.CONTACT_MARGIN_M, mass=PIN_MASS_KG * 0.27)
        shaft.contype, shaft.conaffinity = B.OBJECT_CONTYPE, B.OBJECT_CONAFFINITY
        B.add_box(pin, "pin_head", HEAD_HALF, pos=(0, 0, SHAFT_L_M + HEAD_HALF[2]), rgba=orange,
                  mass=PIN_MASS_KG * 0.73, friction=(HEAD_FRICTION, 0.005, 0.0001))
        add_fixture(spec)
        spec.option.impratio = IMPRATIO
        B.add_cameras(self, spec, look_at=(0.28, 0.0, 0.02))

    def reset(self, model, data, rng) -> dict:
        hole = np.array([rng.uniform(*HOLE_X), rng.uniform(*HOLE_Y), 0.0])
        hole_yaw = rng.uniform(*HOLE_YAW)
        pin = np.array([rng.uniform(*PIN_X), rng.uniform(*PIN_Y), 1e-4])
        B.set_static_pos(model, data, "fixture", hole, hole_yaw)
        B.set_free_pose(model, data, "pin", pin, rng.uniform(*PIN_YAW))
        return {"hole_pos": hole, "hole_yaw": hole_yaw, "pin_start": pin}

    def observe(self, model, data, params) -> dict:
        p, R = B.body_pose(model, data, "pin")
        m = pin_metrics(p, R, params["hole_pos"])
        # the pin relative to the bore, as the stages judge it (tip offset x, y [m], tip above the fixture
        # top [m], tilt [rad]): see peg_insert.observe
        rel = np.array([*m["lateral_m"], m["tip_z_m"] - DEPTH_M, m["tilt_rad"]])
        return {"pin_pos": p, "pin_rot": R, "hole_pos": params["hole_pos"], "hole_yaw": params["hole_yaw"],
                "finger_touch": B.touching(model, data, "pin", FINGERS), "pin_to_hole": rel}

    def detectables(self, model, data, params) -> dict:
        """What a camera's pose estimator could report (TRUE poses, base frame): the pin (its tip frame) and
        the fixture (the bore's axis at the table, its yaw). No contact, no velocity, no hidden parameter."""
        return {"pin": B.body_pose(model, data, "pin"), "hole": B.body_pose(model, data, "fixture")}

    def detect(self, obs, params, memory) -> np.ndarray:
        return detect_tight(obs)

    def final_ok(self, obs, params, memory) -> bool:  # seated, whether or not still held
        return bool(detect_tight(obs)[3])
