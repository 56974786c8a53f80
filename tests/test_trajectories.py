"""Coverage trajectories: limits respected, phases present, save/load, collision checking on a scene."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.trajectories import PHASES, Trajectory, coverage_trajectory, ruckig_move


def _limits():
    q_min = np.array([-2.0, -1.0, -1.5])
    q_max = np.array([2.0, 1.5, 0.5])
    return q_min, q_max, np.array([1.0, 1.5, 2.0]), np.array([0.0, 0.2, -0.5])


def test_coverage_respects_limits_and_has_all_phases(tmp_path):
    q_min, q_max, v_max, home = _limits()
    tr = coverage_trajectory(q_min, q_max, v_max, home, minutes=1.0, rate_hz=100.0, seed=1)
    assert 55 <= tr.duration_s <= 90
    assert np.allclose(np.diff(tr.t), 0.01)
    margin = 0.1 * (q_max - q_min)
    assert np.all(tr.q >= q_min + margin - 1e-9) and np.all(tr.q <= q_max - margin + 1e-9)
    assert np.all(np.abs(tr.qd) <= v_max + 1e-6)
    assert np.all(np.abs(tr.qdd) <= 2 * v_max + 1e-6)
    assert set(np.unique(tr.phase)) == set(range(len(PHASES)))
    fast, slow = tr.phase == PHASES.index("fast"), tr.phase == PHASES.index("slow")
    assert np.abs(tr.qd[fast]).max() > 2 * np.abs(tr.qd[slow]).max()
    # each joint alone reaches both ends of its (shrunk) range in the single-joint phase
    single = tr.q[tr.phase == 0]
    assert np.allclose(single.min(0), q_min + margin) and np.allclose(single.max(0), q_max - margin)
    # continuity: positions move at most v_max * dt per sample
    assert np.all(np.abs(np.diff(tr.q, axis=0)) <= v_max * 0.01 + 1e-6)
    assert not tr.collision_checked
    tr2 = Trajectory.load(tr.save(tmp_path / "traj.npz"))
    np.testing.assert_array_equal(tr2.q, tr.q)
    assert tr2.rate_hz == 100.0 and tr2.joint_names == tr.joint_names


def test_ruckig_move_rest_to_rest():
    q, qd, qdd = ruckig_move(np.zeros(2), np.array([1.0, -0.5]), [1, 1], [2, 2], [20, 20], 100.0)
    assert np.allclose(q[0], 0) and np.allclose(q[-1], [1.0, -0.5])
    assert np.allclose(qd[[0, -1]], 0, atol=1e-9)


def test_collision_checked_on_arm_scene():
    arms = pytest.importorskip("hardware.arms")
    from calibration.trajectories import CollisionChecker, arm_coverage_trajectory

    arm = arms.load_arm("piper")
    checker = CollisionChecker(arm)
    assert not checker.pairs(np.asarray(arm.q_home, float))
    rng = np.random.default_rng(0)
    lim = arm.limits
    hits = sum(bool(checker.pairs(rng.uniform(lim.q_min, lim.q_max))) for _ in range(100))
    assert hits > 0  # random poses do hit the table or the arm itself: the check can fail
    tr = arm_coverage_trajectory("piper", minutes=0.5, seed=3)
    assert tr.collision_checked and tr.arm == "piper"
    assert not checker.collides(tr.q, stride=10)
    assert np.all(tr.q >= lim.q_min - 1e-9) and np.all(tr.q <= lim.q_max + 1e-9)
