"""peg-insert (SIMULATED): pick a square peg from the table and insert it into a fixture's square hole with
1 mm clearance (0.5 mm per side). Stages: grasp, align, insert.

The fixture is four walls around a through hole (MuJoCo primitives have no holes); the table is the hole's
floor. Its pose and the peg's are drawn per episode from the seed. Detectors read: the peg's centre and
axes, the hole's centre and yaw, which fingers touch the peg.
"""

from __future__ import annotations

import numpy as np

from hardware.sim.tasks import base as B

PEG_HALF = (0.010, 0.010, 0.030)  # m: 20 x 20 x 60 mm
PEG_MASS_KG = 0.03
CLEARANCE_M = 0.001  # hole width - peg width
HOLE_HALF = PEG_HALF[0] + CLEARANCE_M / 2  # m
DEPTH_M = 0.025  # fixture height = hole depth
FIXTURE_HALF = 0.035  # m: outer half width
CHAMFER_M = 0.002  # m: 45 deg lead-in around the hole's mouth (machined holes have one; a bare edge jams on
# the follower's +-1 mm wander, docs/tasks.md). The straight part below it is DEPTH_M - CHAMFER_M deep.
RAMP_THICK_M = 0.003  # m: thickness of the slab that forms each chamfer face
FINGERS = ("gripper_body", "gripper_mirror_body")
LIFT_M = 0.01  # grasp: peg bottom this far above the table, held by both fingers
ALIGN_XY_M = 0.001  # align: peg axis within this of the hole axis (either direction of the hole frame)
ALIGN_TILT_RAD = np.deg2rad(3.0)
ALIGN_YAW_RAD = np.deg2rad(2.5)
ALIGN_ABOVE_M = 0.015  # align: peg bottom at most this far above the fixture top
INSERT_DEPTH_M = 0.020  # insert: peg bottom at least this far below the fixture top (of DEPTH_M)
# Episode ranges (world frame, m / rad); the Piper base is at the origin, the table top at z = 0.
PEG_X, PEG_Y, PEG_YAW = (0.24, 0.30), (-0.15, -0.09), (-0.35, 0.35)
HOLE_X, HOLE_Y, HOLE_YAW = (0.26, 0.32), (0.08, 0.14), (-0.35, 0.35)


def wrap_square_yaw(a: np.ndarray | float) -> np.ndarray:
    """Yaw difference of two squares [rad], wrapped to [-pi/4, pi/4) (a square repeats every 90 deg)."""
    return (np.asarray(a, float) + np.pi / 4) % (np.pi / 2) - np.pi / 4


def peg_metrics(peg_pos, peg_rot, hole_pos, hole_yaw) -> dict:
    """Pure geometry: lateral offset of the peg axis in the hole frame [m] (2,), tilt [rad], yaw error [rad],
    height of the peg bottom above the table [m]."""
    peg_pos, R = np.asarray(peg_pos, float), np.asarray(peg_rot, float)
    z = R[:, 2] if R[2, 2] >= 0 else -R[:, 2]  # the peg is symmetric end to end
    bottom = peg_pos - PEG_HALF[2] * z
    c, s = np.cos(hole_yaw), np.sin(hole_yaw)
    d = bottom[:2] - np.asarray(hole_pos, float)[:2]
    lateral = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
    tilt = float(np.arccos(np.clip(z[2], -1.0, 1.0)))
    yaw = float(wrap_square_yaw(np.arctan2(R[1, 0], R[0, 0]) - hole_yaw))
    return {"lateral_m": lateral, "tilt_rad": tilt, "yaw_err_rad": yaw, "bottom_z_m": float(bottom[2])}


def detect_peg(obs: dict) -> np.ndarray:
    """[grasp, align, insert] from observe()'s arrays (pure)."""
    m = peg_metrics(obs["peg_pos"], obs["peg_rot"], obs["hole_pos"], float(obs["hole_yaw"]))
    held = bool(np.all(obs["finger_touch"]))
    grasp = held and m["bottom_z_m"] > LIFT_M
    align = (bool(np.all(np.abs(m["lateral_m"]) <= ALIGN_XY_M)) and m["tilt_rad"] <= ALIGN_TILT_RAD
             and abs(m["yaw_err_rad"]) <= ALIGN_YAW_RAD and m["bottom_z_m"] <= DEPTH_M + ALIGN_ABOVE_M)
    inside = bool(np.all(np.abs(m["lateral_m"]) <= HOLE_HALF))
    insert = inside and m["bottom_z_m"] <= DEPTH_M - INSERT_DEPTH_M
    return np.array([grasp, align, insert])


class PegInsert(B.Task):
    name = "peg-insert"
    title = "pick a 20 mm square peg and insert it into a hole with 1 mm clearance"
    stages = ("grasp", "align", "insert")
    arms = ("piper",)
    episode_s = 40.0

    def add_objects(self, spec, arm) -> None:
        peg = spec.worldbody.add_body(name="peg", pos=[0.27, -0.12, PEG_HALF[2]])
        peg.add_freejoint(name="peg")
        B.add_box(peg, "peg", PEG_HALF, rgba=(0.95, 0.55, 0.1, 1), mass=PEG_MASS_KG,
                  friction=(1.0, 0.005, 0.0001))
        fix = spec.worldbody.add_body(name="fixture", pos=[0.29, 0.11, 0.0], mocap=True)
        w, h, c = FIXTURE_HALF, HOLE_HALF, CHAMFER_M
        lo = (DEPTH_M - c) / 2  # half height of the walls below the chamfer
        t = (w - h) / 2  # wall half thickness
        tc = (w - h - c) / 2  # half thickness of the top rim outside the chamfer
        grey = (0.35, 0.38, 0.45, 1)
        r2 = np.sqrt(0.5)
        for k, ang in enumerate((0.0, np.pi / 2, np.pi, 1.5 * np.pi)):  # the four sides, each rotated about z
            side = fix.add_body(name=f"fixture_side{k}", quat=[np.cos(ang / 2), 0, 0, np.sin(ang / 2)])
            B.add_box(side, f"fixture_wall{k}", (w, t, lo), pos=(0, h + t, lo), rgba=grey)
            B.add_box(side, f"fixture_rim{k}", (w, tc, c / 2), pos=(0, h + c + tc, DEPTH_M - c / 2),
                      rgba=grey)
            ramp = B.add_box(side, f"fixture_chamfer{k}", (w - c, c / r2 / 2, RAMP_THICK_M / 2),
                             pos=(0, h + c / 2 + RAMP_THICK_M / 2 * r2,
                                  DEPTH_M - c / 2 - RAMP_THICK_M / 2 * r2),
                             rgba=grey)
            ramp.quat = [np.cos(np.pi / 8), np.sin(np.pi / 8), 0, 0]  # 45 deg about x: the slab's face
        B.add_cameras(self, spec, look_at=(0.28, 0.0, 0.02))

    def reset(self, model, data, rng) -> dict:
        hole = np.array([rng.uniform(*HOLE_X), rng.uniform(*HOLE_Y), 0.0])
        hole_yaw = rng.uniform(*HOLE_YAW)
        peg = np.array([rng.uniform(*PEG_X), rng.uniform(*PEG_Y), PEG_HALF[2] + 1e-4])
        B.set_static_pos(model, data, "fixture", hole, hole_yaw)
        B.set_free_pose(model, data, "peg", peg, rng.uniform(*PEG_YAW))
        return {"hole_pos": hole, "hole_yaw": hole_yaw, "peg_start": peg}

    def observe(self, model, data, params) -> dict:
        p, R = B.body_pose(model, data, "peg")
        m = peg_metrics(p, R, params["hole_pos"], params["hole_yaw"])
        # the peg relative to the hole, as the stages judge it (lateral x, y in the hole frame [m], bottom
        # above the fixture top [m], yaw error [rad]): the millimetre that decides alignment is a small
        # difference of two world positions spread over centimetres, so a policy is given it directly, as
        # low-dimensional behaviour cloning is given object-relative poses (robomimic)
        rel = np.array([*m["lateral_m"], m["bottom_z_m"] - DEPTH_M, m["yaw_err_rad"]])
        return {"peg_pos": p, "peg_rot": R, "hole_pos": params["hole_pos"], "hole_yaw": params["hole_yaw"],
                "finger_touch": B.touching(model, data, "peg", FINGERS), "peg_to_hole": rel}

    def detect(self, obs, params, memory) -> np.ndarray:
        return detect_peg(obs)

    def final_ok(self, obs, params, memory) -> bool:  # inserted, whether or not still held
        return bool(detect_peg(obs)[2])

    def detectables(self, model, data, params) -> dict:  # the peg, and the hole (the fixture's frame)
        return {"peg": B.body_pose(model, data, "peg"), "hole": B.body_pose(model, data, "fixture")}
