"""Twin tasks (SIMULATED): stage detectors on scripted states (success and near misses), ordered latching,
the progress metric, seeded initial conditions, and the task registry's errors."""

import mujoco
import numpy as np
import pytest

from hardware.arms import load_arm
from hardware.errors import ConfigError
from hardware.sim.tasks import TASKS, StageTracker, get_task, scene_model, task_progress
from hardware.sim.tasks import peg_insert as PEG
from hardware.sim.tasks.base import latch_stages


def _rz(yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _peg_obs(bottom_xy, bottom_z, yaw=0.3, hole_yaw=0.3, tilt=0.0, held=(True, True)):
    hole = np.array([0.3, 0.1, 0.0])
    R = _rz(yaw) @ np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    c, s = np.cos(hole_yaw), np.sin(hole_yaw)
    bottom = hole + np.array([c * bottom_xy[0] - s * bottom_xy[1], s * bottom_xy[0] + c * bottom_xy[1],
                              bottom_z])
    return {"peg_pos": bottom + PEG.PEG_HALF[2] * R[:, 2], "peg_rot": R, "hole_pos": hole,
            "hole_yaw": hole_yaw, "finger_touch": np.array(held)}


def test_peg_detectors_success_and_near_misses():
    lifted = _peg_obs((0.05, 0.0), 0.05)
    assert PEG.detect_peg(lifted).tolist() == [True, False, False]
    assert PEG.detect_peg(_peg_obs((0.05, 0.0), 0.05, held=(True, False)))[0] == np.False_  # one finger
    assert PEG.detect_peg(_peg_obs((0.05, 0.0), 0.005))[0] == np.False_  # not lifted
    above = _peg_obs((0.0004, -0.0004), PEG.DEPTH_M + 0.01)
    assert PEG.detect_peg(above).tolist() == [True, True, False]
    assert not PEG.detect_peg(_peg_obs((0.0015, 0.0), PEG.DEPTH_M + 0.01))[1]  # 1.5 mm off
    assert not PEG.detect_peg(_peg_obs((0.0, 0.0), PEG.DEPTH_M + 0.01, yaw=0.3 + np.deg2rad(4)))[1]
    assert PEG.detect_peg(_peg_obs((0.0, 0.0), PEG.DEPTH_M + 0.01, yaw=0.3 + np.pi / 2))[1]  # square symmetry
    assert not PEG.detect_peg(_peg_obs((0.0, 0.0), PEG.DEPTH_M + 0.01, tilt=np.deg2rad(5)))[1]
    assert not PEG.detect_peg(_peg_obs((0.0, 0.0), PEG.DEPTH_M + 0.03))[1]  # too high
    inside = _peg_obs((0.0003, 0.0), 0.002, held=(False, False))
    assert PEG.detect_peg(inside)[2]
    assert not PEG.detect_peg(_peg_obs((0.0003, 0.0), PEG.DEPTH_M - 0.015))[2]  # only 15 of 20 mm in
    assert not PEG.detect_peg(_peg_obs((0.02, 0.0), 0.002))[2]  # beside the fixture, on the table
    assert PEG.detect_peg(_peg_obs((0.0, 0.0), 0.002, tilt=np.pi))[2]  # upside down counts (symmetric)


def test_stages_latch_in_order_and_progress():
    tr = StageTracker(("a", "b", "c"))
    assert tr.update([False, True, True], 1.0) == []  # b, c cannot come before a
    assert tr.update([True, False, False], 2.0) == ["a"]
    assert tr.update([False, True, True], 3.0) == ["b", "c"]
    assert tr.done.all() and tr.progress == 1.0 and tr.t_done.tolist() == [2.0, 3.0, 3.0]
    assert task_progress(np.array([True, False, False])) == pytest.approx(1 / 3)
    assert latch_stages(np.array([True, False]), np.array([False, False])).tolist() == [True, False]


@pytest.mark.parametrize("name", sorted(TASKS))
def test_seeds_reproduce_initial_conditions(name):
    task = get_task(name)
    m = scene_model(load_arm("piper"), "table", task)
    d = mujoco.MjData(m)

    def draw(seed):
        p = task.reset(m, d, np.random.default_rng(seed))
        mujoco.mj_forward(m, d)
        return np.concatenate([d.qpos.copy(), d.mocap_pos.ravel().copy()]), p

    a, pa = draw(3)
    b, _ = draw(4)
    c, pc = draw(3)
    assert np.array_equal(a, c) and not np.array_equal(a, b)
    assert all(np.array_equal(np.asarray(pa[k]), np.asarray(pc[k])) for k in pa)
    assert {"task_scene", "wrist"} <= {m.camera(i).name for i in range(m.ncam)}


def test_registry_errors_are_one_line():
    with pytest.raises(ConfigError, match="unknown task"):
        get_task("juggle")
    with pytest.raises(ConfigError, match="does not fit"):
        scene_model(load_arm("panda"), "table", get_task("peg-insert"))


def test_wipe_detectors_force_band_and_coverage():
    from hardware.sim.tasks import wipe as W

    params = {"area_pos": np.array([0.3, 0.0, 0.0]), "area_yaw": 0.2}
    c, s = np.cos(0.2), np.sin(0.2)

    def obs(lx, ly, z=0.0, f=8.0):
        return {"tip_pos": np.array([0.3 + c * lx - s * ly, s * lx + c * ly, z]), "force_n": f}

    empty = np.zeros(W.grid_shape(), bool)
    flags, cov = W.detect_wipe(obs(0.0, 0.0, z=0.05, f=0.0), params, empty)
    assert flags.tolist() == [False, False, False] and not cov.any()  # above the mark
    flags, cov = W.detect_wipe(obs(0.0, 0.0, f=45.0), params, empty)
    assert flags.tolist() == [True, False, False] and not cov.any()  # pressing too hard wipes nothing
    flags, cov = W.detect_wipe(obs(0.06, 0.0), params, empty)
    assert not flags[0] and not cov.any()  # beside the mark
    cov = empty
    for lx in np.arange(-0.035, 0.036, 0.01):  # three strokes along the mark
        for ly in (-0.02, 0.0, 0.02):
            flags, cov = W.detect_wipe(obs(lx, ly), params, cov)
    assert flags.tolist() == [True, True, True] and cov.mean() >= W.COVERAGE_MIN
    part = empty
    for lx in np.arange(-0.035, 0.036, 0.01):  # one stroke: a near miss on coverage
        _, part = W.detect_wipe(obs(lx, 0.0), params, part)
    assert part.mean() < W.COVERAGE_MIN


def test_press_fit_detectors_seat_and_near_misses():
    from hardware.sim.tasks import press_fit as P

    base = np.array([0.3, 0.1, 0.0])
    h = 0.5 * (P.SKIRT_H_M + P.CAP_H_M)

    def obs(dx=0.0, edge=0.0, yaw=0.0, tilt=0.0, held=(True, True)):
        ct, st = np.cos(tilt), np.sin(tilt)
        R = _rz(yaw) @ np.array([[1, 0, 0], [0, ct, -st], [0, st, ct]])
        return {"block_pos": base + [dx, 0.0, P.PLATE_TOP_M + edge + h], "block_rot": R, "base_pos": base,
                "base_yaw": 0.0, "finger_touch": np.array(held)}

    assert P.detect_press(obs(edge=0.0)).tolist()[1:] == [True, True]  # seated (grasp latched earlier)
    assert P.detect_press(obs(edge=0.03))[0]  # held and lifted
    assert P.detect_press(obs(edge=0.008))[1] and not P.detect_press(obs(edge=0.008))[2]  # on the studs
    assert not P.detect_press(obs(edge=0.002))[2]  # 2 mm short of seated
    assert not P.detect_press(obs(dx=0.003))[1]  # 3 mm off
    assert not P.detect_press(obs(yaw=np.deg2rad(6)))[1]
    assert P.detect_press(obs(yaw=np.pi / 2))[2]  # square symmetry
    assert not P.detect_press(obs(tilt=np.deg2rad(4)))[2]
    on_table = {**obs(), "block_pos": np.array([0.25, -0.1, h])}
    assert not P.detect_press(on_table)[0]  # touched but not lifted
