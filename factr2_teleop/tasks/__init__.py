"""Scripted demonstrations of the twin tasks through the full teleop stack (SIMULATED): the operator that
drives the leader (operator.py), its IK (kinematics.py), the task scripts (scripts.py primitives, place.py,
wipe.py), the per-tick episode driver (collect.py) and `factr2 collect` as a function (run.py)."""

from __future__ import annotations


def script_for(task_name: str):
    """The demonstration script (a generator function (op, params, rng)) of a task."""
    from factr2_teleop.tasks import place, screw, tight, wipe

    return {"peg-insert": place.peg_insert, "press-fit": place.press_fit, "wipe": wipe.wipe,
            "tight-insert": tight.tight_insert, "cap-screw": screw.cap_screw}[task_name]
