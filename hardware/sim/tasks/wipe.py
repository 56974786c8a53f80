"""wipe (SIMULATED): wipe a marked area of the table with the closed gripper while pressing within a force
band. Stages: reach, contact (within the band, inside the area), coverage (>= 80 % of the area's cells
wiped within the band).

The mark is a visual-only patch (no collision) on the table; the tool is the pair of closed fingers. A 1 cm
grid over the mark counts as wiped the cells within TOOL_RADIUS_M of the fingertips' centre on every decision
where the fingers press the table with a force inside the band.
"""

from __future__ import annotations

import numpy as np

from hardware.sim.tasks import base as B

AREA_HALF = (0.04, 0.03)  # m: an 80 x 60 mm mark
CELL_M = 0.01
TOOL_RADIUS_M = 0.012  # m: the closed fingers' footprint (24 x 20 mm) as a disc
FORCE_BAND_N = (2.0, 30.0)  # N: normal force of the fingers on the table that counts as wiping
COVERAGE_MIN = 0.8
REACH_HEIGHT_M = 0.02  # reach: fingertips within this of the table, over the mark
FINGERS = ("gripper_body", "gripper_mirror_body")
TIP_OFFSET_M = 0.01  # fingertips beyond the ee site along the approach axis
AREA_X, AREA_Y, AREA_YAW = (0.27, 0.33), (-0.06, 0.06), (-0.3, 0.3)


def grid_shape() -> tuple[int, int]:
    return round(2 * AREA_HALF[0] / CELL_M), round(2 * AREA_HALF[1] / CELL_M)


def to_area(xy, center, yaw) -> np.ndarray:
    """World xy [m] -> the mark's frame (origin at its centre, x along its long side)."""
    c, s = np.cos(yaw), np.sin(yaw)
    d = np.asarray(xy, float)[:2] - np.asarray(center, float)[:2]
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def wiped_cells(local_xy) -> np.ndarray:
    """Bool grid: cells whose centres lie within TOOL_RADIUS_M of a tool position in the mark's frame."""
    nx, ny = grid_shape()
    cx = -AREA_HALF[0] + CELL_M * (np.arange(nx) + 0.5)
    cy = -AREA_HALF[1] + CELL_M * (np.arange(ny) + 0.5)
    dx, dy = cx[:, None] - local_xy[0], cy[None, :] - local_xy[1]
    return dx * dx + dy * dy <= TOOL_RADIUS_M ** 2


def in_band(force_n: float) -> bool:
    return FORCE_BAND_N[0] <= force_n <= FORCE_BAND_N[1]


def detect_wipe(obs: dict, params: dict, covered: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """([reach, contact, coverage], the new wiped grid) from observe()'s arrays (pure)."""
    local = to_area(obs["tip_pos"], params["area_pos"], params["area_yaw"])
    over = bool(np.all(np.abs(local) <= AREA_HALF))
    reach = over and obs["tip_pos"][2] <= REACH_HEIGHT_M
    contact = over and in_band(float(obs["force_n"]))
    covered = covered | wiped_cells(local) if contact else covered
    return np.array([reach, contact, covered.mean() >= COVERAGE_MIN]), covered


class Wipe(B.Task):
    name = "wipe"
    title = "wipe an 80 x 60 mm mark with the closed gripper, pressing 2-30 N"
    stages = ("reach", "contact", "coverage")
    arms = ("piper",)
    episode_s = 40.0

    def add_objects(self, spec, arm) -> None:
        mark = spec.worldbody.add_body(name="mark", pos=[0.3, 0.0, 0.0], mocap=True)
        B.add_box(mark, "mark", (AREA_HALF[0], AREA_HALF[1], 0.0004), pos=(0, 0, 0.0004),
                  rgba=(0.2, 0.7, 0.95, 1), collide=False)
        B.add_cameras(self, spec, look_at=(0.3, 0.0, 0.0))

    def reset(self, model, data, rng) -> dict:
        p = np.array([rng.uniform(*AREA_X), rng.uniform(*AREA_Y), 0.0])
        yaw = rng.uniform(*AREA_YAW)
        B.set_static_pos(model, data, "mark", p, yaw)
        return {"area_pos": p, "area_yaw": yaw}

    def observe(self, model, data, params) -> dict:
        import mujoco

        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "ee")
        R = data.site_xmat[sid].reshape(3, 3)
        return {"tip_pos": data.site_xpos[sid] + TIP_OFFSET_M * R[:, 2],
                "force_n": sum(B.contact_force_between(model, data, f, ("world",)) for f in FINGERS)}

    def detect(self, obs, params, memory) -> np.ndarray:
        covered = memory.get("covered", np.zeros(grid_shape(), bool))
        flags, memory["covered"] = detect_wipe(obs, params, covered)
        return flags

    def final_ok(self, obs, params, memory) -> bool:
        return bool(memory.get("covered", np.zeros(1)).mean() >= COVERAGE_MIN)

    def detectables(self, model, data, params) -> dict:  # the mark (a printed patch: a tag-like target)
        return {"area": B.body_pose(model, data, "mark")}
