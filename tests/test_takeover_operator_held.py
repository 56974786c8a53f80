"""The twin takeover operator with the object already in the hand (factr2_teleop/tasks/takeover_operator.py,
place.py): it carries the object on -- over the target, line up, push -- and never opens the gripper or lifts
away to grasp again (the start-over corrections that taught a DAgger round "start over", docs/takeover.md)."""

import numpy as np

from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks.place import PEG_PLACE, peg_insert
from factr2_teleop.tasks.takeover_operator import finish_script


class StubOperator:
    """What the scripts read and write: the percept (obs, T_ee), the gripper, the aim."""

    def __init__(self, T_ee, obs):
        self.p = type("P", (), {"obs": obs, "T_ee": T_ee})()
        self._T = T_ee.copy()
        self.grip, self.nudge, self.aims, self.log = 1.0, np.zeros(2), [], None

    def ee_pose_des(self):
        return self._T.copy()

    def aim(self, T):
        self._T = T.copy()
        self.aims.append(T.copy())


def _scene():
    hole = np.array([0.30, 0.10, 0.0])
    T_ee = K.pose(K.down_rotation(0.0), hole + [0.01, -0.02, 0.12])  # near the hole, peg in hand
    peg = T_ee[:3, 3] - [0.0, 0.0, PEG_PLACE.grasp_below_m - PEG_PLACE.half_h]
    obs = {"peg_pos": peg, "peg_rot": np.eye(3), "finger_touch": np.array([True, True])}
    return T_ee, obs, {"hole_pos": hole, "hole_yaw": 0.0}


def _run(script, op, steps):
    next(script)
    for _ in range(steps):
        try:
            next(script)
        except StopIteration:
            break


def test_held_peg_is_carried_on_to_the_hole_not_grasped_again():
    T_ee, obs, params = _scene()
    op = StubOperator(T_ee, obs)
    _run(peg_insert(op, params, np.random.default_rng(0), held=True), op, 60)
    z = np.array([T[2, 3] for T in op.aims])
    xy = np.array([T[:2, 3] for T in op.aims])
    assert op.grip == 1.0  # never opened
    assert z.max() <= T_ee[2, 3] + 0.005  # no lift away (the demonstration lifts 7 cm over the grasp)
    hole = params["hole_pos"][:2]
    assert np.linalg.norm(xy[-1] - hole) < np.linalg.norm(T_ee[:2, 3] - hole)  # on its way there


def test_finish_script_takes_the_held_path_when_the_fingers_hold_it():
    T_ee, obs, params = _scene()
    a, b = StubOperator(T_ee, obs), StubOperator(T_ee, obs)
    _run(finish_script("peg-insert")(a, params, np.random.default_rng(3)), a, 40)
    _run(peg_insert(b, params, np.random.default_rng(3), held=True), b, 40)
    assert len(a.aims) == len(b.aims) > 0
    assert all(np.allclose(x, y) for x, y in zip(a.aims, b.aims))
