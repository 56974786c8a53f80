"""press-fit (SIMULATED, LEGO-like): pick a block and press it onto four studs until it is seated.
Stages: grasp, align, seat.

The base plate carries a 2 x 2 grid of square studs; the block is a cap whose four skirt walls close around
the round studs with an interference of INTERFERENCE_M per side. The studs' contacts are soft (STUD_SOLREF, a
time constant of 10 ms against the table's 4 ms), so the skirt slides over them only when pressed: the
squeezed studs push the walls outward and friction resists, the clutch of a real brick. Seated: the skirt's
lower edge within SEAT_TOL_M of the plate and the block level.
"""

from __future__ import annotations

import mujoco
import numpy as np

from hardware.sim.tasks import base as B

STUD_R_M = 0.004  # m: round studs (capsules: 8 mm across, a rounded top that leads the skirt in)
STUD_HALF = (STUD_R_M, STUD_R_M, 0.004)  # m: half extents of one stud (8 mm tall above the plate)
STUD_PITCH_M = 0.016
PLATE_HALF = (0.03, 0.03, 0.004)  # m: the base plate (its top at 8 mm)
INTERFERENCE_M = 0.0002  # m per side: the skirt's inside is this much narrower than the studs' outside
WALL_M = 0.003  # m: skirt wall thickness
SKIRT_H_M = 0.009  # m: skirt height: 1 mm more than the studs, so a seated block rests on its skirt (stiff
# contact with the plate), not on the soft stud tops, which pushed a pressed block back up by ~1 mm
CAP_H_M = 0.012  # m: solid top part of the block
BLOCK_MASS_KG = 0.02
STUD_SOLREF = (0.01, 1.0)
STUD_SOLIMP = (0.9, 0.99, 0.001, 0.5, 2.0)
FINGERS = ("gripper_body", "gripper_mirror_body")
LIFT_M = 0.01
ALIGN_XY_M = 0.0015
ALIGN_YAW_RAD = np.deg2rad(4.0)
ALIGN_ABOVE_M = 0.012  # align: skirt edge at most this far above the studs' tops
SEAT_TOL_M = 0.0008
SEAT_TILT_RAD = np.deg2rad(2.0)
STUD_OUT = STUD_PITCH_M / 2 + STUD_HALF[0]  # m: half extent of the stud group (12 mm)
INNER_HALF = STUD_OUT - INTERFERENCE_M  # m: the skirt's inner half width
OUTER_HALF = INNER_HALF + WALL_M
PLATE_TOP_M = 2 * PLATE_HALF[2]
BLOCK_X, BLOCK_Y, BLOCK_YAW = (0.24, 0.30), (-0.15, -0.09), (-0.35, 0.35)
BASE_X, BASE_Y, BASE_YAW = (0.26, 0.32), (0.08, 0.14), (-0.35, 0.35)


def block_metrics(block_pos, block_rot, base_pos, base_yaw) -> dict:
    """Pure geometry: lateral offset of the block centre from the stud group's in the base frame [m] (2,),
    tilt [rad], yaw error wrapped to the square's symmetry [rad], skirt edge above the plate top [m]."""
    R = np.asarray(block_rot, float)
    p = np.asarray(block_pos, float)
    c, s = np.cos(base_yaw), np.sin(base_yaw)
    d = p[:2] - np.asarray(base_pos, float)[:2]
    yaw = (np.arctan2(R[1, 0], R[0, 0]) - base_yaw + np.pi / 4) % (np.pi / 2) - np.pi / 4
    edge = p[2] - R[2, 2] * 0.5 * (SKIRT_H_M + CAP_H_M)  # the body frame sits mid-height of the block
    return {"lateral_m": np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]]),
            "tilt_rad": float(np.arccos(np.clip(R[2, 2], -1, 1))), "yaw_err_rad": float(yaw),
            "edge_above_plate_m": float(edge - PLATE_TOP_M)}


def detect_press(obs: dict) -> np.ndarray:
    """[grasp, align, seat] from observe()'s arrays (pure)."""
    m = block_metrics(obs["block_pos"], obs["block_rot"], obs["base_pos"], float(obs["base_yaw"]))
    on_table_z = 0.5 * (SKIRT_H_M + CAP_H_M)
    grasp = bool(np.all(obs["finger_touch"])) and obs["block_pos"][2] > on_table_z + LIFT_M
    level = m["tilt_rad"] <= SEAT_TILT_RAD
    align = (bool(np.all(np.abs(m["lateral_m"]) <= ALIGN_XY_M)) and abs(m["yaw_err_rad"]) <= ALIGN_YAW_RAD
             and level and m["edge_above_plate_m"] <= 2 * STUD_HALF[2] + ALIGN_ABOVE_M)
    seat = bool(np.all(np.abs(m["lateral_m"]) <= ALIGN_XY_M)) and level and \
        abs(m["edge_above_plate_m"]) <= SEAT_TOL_M
    return np.array([grasp, align, seat])


class PressFit(B.Task):
    name = "press-fit"
    title = "pick a 30 mm block and press it onto four studs until seated (0.2 mm interference)"
    stages = ("grasp", "align", "seat")
    arms = ("piper",)
    episode_s = 40.0

    def add_objects(self, spec, arm) -> None:
        h = 0.5 * (SKIRT_H_M + CAP_H_M)
        blk = spec.worldbody.add_body(name="block", pos=[0.27, -0.12, h])
        blk.add_freejoint(name="block")
        red = (0.85, 0.15, 0.12, 1)
        B.add_box(blk, "block_cap", (OUTER_HALF, OUTER_HALF, CAP_H_M / 2), pos=(0, 0, h - CAP_H_M / 2),
                  rgba=red, mass=BLOCK_MASS_KG * 0.6, friction=(1.0, 0.005, 0.0001))
        z = -h + SKIRT_H_M / 2
        t = WALL_M / 2
        for k, sy in enumerate((1, -1)):
            B.add_box(blk, f"block_skirt_y{k}", (OUTER_HALF, t, SKIRT_H_M / 2),
                      pos=(0, sy * (INNER_HALF + t), z),
                      rgba=red, mass=BLOCK_MASS_KG * 0.1)
        for k, sx in enumerate((1, -1)):
            B.add_box(blk, f"block_skirt_x{k}", (t, INNER_HALF, SKIRT_H_M / 2),
                      pos=(sx * (INNER_HALF + t), 0, z),
                      rgba=red, mass=BLOCK_MASS_KG * 0.1)
        base = spec.worldbody.add_body(name="base", pos=[0.29, 0.11, 0.0], mocap=True)
        B.add_box(base, "base_plate", PLATE_HALF, pos=(0, 0, PLATE_HALF[2]), rgba=(0.2, 0.55, 0.25, 1))
        for i, sx in enumerate((1, -1)):
            for j, sy in enumerate((1, -1)):
                x, y = sx * STUD_PITCH_M / 2, sy * STUD_PITCH_M / 2
                base.add_geom(name=f"stud{i}{j}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[STUD_R_M, 0, 0],
                                  fromto=[x, y, PLATE_TOP_M, x, y, PLATE_TOP_M + 2 * STUD_HALF[2] - STUD_R_M],
                                  rgba=[0.25, 0.65, 0.3, 1], solref=list(STUD_SOLREF),
                                  solimp=list(STUD_SOLIMP),
                                  friction=[0.8, 0.005, 0.0001], contype=B.OBJECT_CONTYPE,
                                  conaffinity=B.OBJECT_CONAFFINITY)
        B.add_cameras(self, spec, look_at=(0.28, 0.0, 0.02))

    def reset(self, model, data, rng) -> dict:
        base = np.array([rng.uniform(*BASE_X), rng.uniform(*BASE_Y), 0.0])
        base_yaw = rng.uniform(*BASE_YAW)
        blk = np.array([rng.uniform(*BLOCK_X), rng.uniform(*BLOCK_Y), 0.5 * (SKIRT_H_M + CAP_H_M) + 1e-4])
        B.set_static_pos(model, data, "base", base, base_yaw)
        B.set_free_pose(model, data, "block", blk, rng.uniform(*BLOCK_YAW))
        return {"base_pos": base, "base_yaw": base_yaw, "block_start": blk}

    def observe(self, model, data, params) -> dict:
        p, R = B.body_pose(model, data, "block")
        m = block_metrics(p, R, params["base_pos"], params["base_yaw"])
        # the block relative to the studs, as the stages judge it (lateral x, y in the base frame [m], skirt
        # edge above the plate [m], yaw error [rad]): see peg_insert.observe
        rel = np.array([*m["lateral_m"], m["edge_above_plate_m"], m["yaw_err_rad"]])
        return {"block_pos": p, "block_rot": R, "base_pos": params["base_pos"],
                "base_yaw": params["base_yaw"],
                "finger_touch": B.touching(model, data, "block", FINGERS), "block_to_base": rel}

    def detect(self, obs, params, memory) -> np.ndarray:
        return detect_press(obs)

    def final_ok(self, obs, params, memory) -> bool:
        return bool(detect_press(obs)[2])

    def detectables(self, model, data, params) -> dict:  # the block, and the base plate with its studs
        return {"block": B.body_pose(model, data, "block"), "base": B.body_pose(model, data, "base")}
