"""The PRIVILEGED state observation (twins only, SIMULATED): a twin task's object state as one flat float
vector, a policy input in place of (or beside) camera frames (`factr2 train --obs state`); and which object
input each observation takes (OBSERVATIONS: `--obs perceived` takes the simulated detector's vector instead,
hardware/sim/perception.py seen_vector, docs/perception.md).

Order (fixed per task, recorded with the data as the /task/objects channel's `names`): every entry of
`task.observe(model, data, params)` in its dict order, then every entry of the episode's `params` that
observe() does not already hold, in their dict order; each entry flattened row-major, booleans as 0 / 1.
For the built-in tasks (positions [m], rotation-matrix entries [1], yaws [rad], contacts 0/1, force [N]):

    peg-insert (25)  peg_pos 3, peg_rot 9, hole_pos 3, hole_yaw 1, finger_touch 2, peg_to_hole 4, peg_start 3
    press-fit  (25)  block_pos 3, block_rot 9, base_pos 3, base_yaw 1, finger_touch 2, block_to_base 4,
                     block_start 3
    wipe        (8)  tip_pos 3, force_n 1, area_pos 3, area_yaw 1

Why the params too: wipe's observe() reads only the fingertip and the pressing force, so without the mark's
pose (a parameter) a policy could not know where to wipe. Real hardware has no such vector: a policy trained
on it runs on twins only, and its results are labelled so.

    vec = task_state_vector(task, model, data, params)        # live, at rollout: float32 (D,)
    batch["objects"] = torch.from_numpy(normaliser.norm("objects", vec[None]))   # the policy's (1, D) input
"""

from __future__ import annotations

import numpy as np

from hardware.recording import schemas as S

# PolicyConfig.observation / `factr2 train --obs`. "perceived" is the object input a camera-based pose
# estimator could give (SIMULATED, not privileged: the twin's simulated detector, hardware/sim/perception.py,
# recorded live on /perceived/objects: per object its pose, visible flag and detection age), in place of the
# privileged "state"; the model takes either as its `objects` input.
# "joints": nothing besides the joints and the force (no frames, no objects): a blind policy, which runs on
# any rig -- the crash campaign rolls one out against a twin in another process, which has no cameras and
# no task world (bench/crash_trials.py); it cannot see a task, so it is for the machinery, not a task.
OBSERVATIONS = ("images", "state", "images+state", "perceived", "images+perceived", "joints")
OBJECT_INPUTS = {"state": S.TASK_OBJECTS_FEATURE, "perceived": S.PERCEIVED_FEATURE}  # part -> feature


def uses_images(observation: str) -> bool:
    return "images" in observation.split("+")


def objects_feature(observation: str) -> str | None:
    """The recorded feature an observation takes its object vector from (None: no object input)."""
    parts = [OBJECT_INPUTS[p] for p in observation.split("+") if p in OBJECT_INPUTS]
    return parts[0] if parts else None


def uses_objects(observation: str) -> bool:
    return objects_feature(observation) is not None


def low_dimensional(observation: str) -> bool:
    """No camera frames: an object vector, or nothing besides the joints and force (the `state` preset's
    input)."""
    return not uses_images(observation)


def _entries(obs: dict, params: dict) -> list[tuple[str, np.ndarray]]:
    out = [(k, np.asarray(v, dtype=float).ravel()) for k, v in obs.items()]
    # a param named with a leading underscore is hidden from every observation (cap-screw's thread friction,
    # strip torque: what the task is built to leave unobserved), even the privileged one
    out += [(k, np.asarray(v, dtype=float).ravel()) for k, v in params.items()
            if k not in obs and not k.startswith("_")]
    return out


def objects_vector(obs: dict, params: dict) -> tuple[np.ndarray, list[str]]:
    """(vector float32 (D,), element names ("peg_pos.0", ...)) from observe()'s dict and the episode's
    params (pure)."""
    entries = _entries(obs, params)
    names = [f"{k}.{i}" for k, v in entries for i in range(v.size)]
    vec = np.concatenate([v for _, v in entries]) if entries else np.zeros(0)
    return vec.astype(np.float32), names


def task_state_vector(task, model, data, params: dict) -> np.ndarray:
    """The privileged vector of a live twin task now (float32 (D,)), in the order the recordings hold
    (objects_vector). Call it on the thread that steps the physics, or under the world's lock."""
    return objects_vector(task.observe(model, data, params), params)[0]
