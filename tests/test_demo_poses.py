"""The demo task's poses for an arm without the Piper's joint layout (factr2_teleop/demo/poses.py)."""

from __future__ import annotations

import numpy as np

from factr2_teleop.demo.poses import press_pose, turned_over
from hardware.arms import load_arm
from hardware.arms.dynamics import ArmDynamics


def test_press_pose_moves_the_tool_straight_down():
    arm = load_arm("piper")
    dyn = ArmDynamics(arm)
    q0 = np.asarray(arm.q_home, float) + np.array([0.0, 0.5, -0.4, 0.0, 0.3, 0.0])
    q = press_pose(dyn.fk, dyn.jacobian, q0, 0.05)
    np.testing.assert_allclose(dyn.fk(q)[:3, 3], dyn.fk(q0)[:3, 3] - [0.0, 0.0, 0.05], atol=2e-4)


def test_turned_over_points_the_tool_at_the_table_centre():
    arm = load_arm("piper")
    dyn = ArmDynamics(arm)
    q0 = np.asarray(arm.q_home, float) + np.array([2.0, 0.5, -0.4, 0.0, 0.0, 0.0])
    q = turned_over(q0, dyn.fk(q0)[:2, 3], np.array([0.3, 0.2]))
    xy = dyn.fk(q)[:2, 3]
    assert abs(np.arctan2(xy[1], xy[0]) - np.arctan2(0.2, 0.3)) < 1e-6
    np.testing.assert_allclose(q[1:], q0[1:])
