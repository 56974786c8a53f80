"""What the scripted operator sees when it looks through the simulated camera (SIMULATED): the task's
observe() arrays and episode params with every detectable object's pose replaced by the PoseDetector's
(hardware/sim/perception.py), never the twin's truth.

    view = OperatorView()                                   # per collection; view.reset() per episode
    obs_seen, params_seen = view.look(obs, params, seen, T_ee)

Naming (Task.detectables): a detectable `n` stands in for observe()'s / the params' `n_pos`, `n_rot` and
`n_yaw`. A person also knows what is in their hand: an object the fingers hold (observe()'s finger_touch,
seen and felt through the trigger) that the camera cannot see (the hand hides it) is taken to move with
the gripper from where it was last seen when grasped -- the operator's belief, wrong by whatever the last
view was wrong by (bias, noise) and by any slip in the fingers since.
"""

from __future__ import annotations

import numpy as np


def yaw_of(R) -> float:
    R = np.asarray(R, float)
    return float(np.arctan2(R[1, 0], R[0, 0]))


def carried(T_ee, T_ee_grasp, pos, rot) -> tuple[np.ndarray, np.ndarray]:
    """The pose (position [m], rotation) of an object that was at (pos, rot) when the gripper was at
    T_ee_grasp (4x4) and has moved rigidly with it to T_ee (pure)."""
    T_obj = np.eye(4)
    T_obj[:3, :3], T_obj[:3, 3] = rot, pos
    T = np.asarray(T_ee, float) @ np.linalg.inv(np.asarray(T_ee_grasp, float)) @ T_obj
    return T[:3, 3].copy(), T[:3, :3].copy()


def substitute(d: dict, name: str, pos, rot) -> dict:
    """d with `name`_pos / _rot / _yaw (those d holds) replaced by a seen pose (pure; a copy)."""
    out = dict(d)
    if f"{name}_pos" in out:
        out[f"{name}_pos"] = np.asarray(pos, float)
    if f"{name}_rot" in out:
        out[f"{name}_rot"] = np.asarray(rot, float)
    if f"{name}_yaw" in out:
        out[f"{name}_yaw"] = yaw_of(rot)
    return out


class OperatorView:
    """The operator's belief about the detectable objects, one episode at a time."""

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self._grasp: dict = {}  # name -> (T_ee at the grasp, pos, rot seen then) while held

    def look(self, obs: dict, params: dict, seen: dict, T_ee) -> tuple[dict, dict]:
        """(obs, params) as seen: detectables from `seen` (name -> Seen), a held hidden object carried by
        the gripper (T_ee: the gripper pose, 4x4 [m]). A never-seen object reads NaN."""
        held = bool(np.all(obs["finger_touch"])) if "finger_touch" in obs else False
        o, p = dict(obs), dict(params)
        for name, s in seen.items():
            pos, rot = s.pos_m, s.rot
            movable = f"{name}_rot" in obs  # observe() has its rotation: it moves (a peg), not a fixture
            if movable and held:
                if name not in self._grasp:
                    self._grasp[name] = (np.array(T_ee, float), pos, rot)
                if not s.visible:
                    T_g, p_g, r_g = self._grasp[name]
                    pos, rot = carried(T_ee, T_g, p_g, r_g)
            else:
                self._grasp.pop(name, None)
            o = substitute(o, name, pos, rot)
            p = substitute(p, name, pos, rot)
        return o, p
