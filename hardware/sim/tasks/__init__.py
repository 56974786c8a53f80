"""Contact-rich tasks on the twins (SIMULATED): objects, seeded initial conditions, stage detectors.

    from hardware.sim.tasks import get_task, TASKS
    task = get_task("peg-insert")     # ConfigError (one line) for an unknown name
    task.stages                       # ("grasp", "align", "insert")

A twin builds a task's scene when its rig's TwinSpec names one (`[twin] task = "..."`) or when Twin(...,
task=...) is given (hardware/sim/twin.py); see base.py for the pieces and docs/tasks.md for each task.
"""

from __future__ import annotations

from hardware.errors import ConfigError
from hardware.sim.tasks.base import StageTracker, Task, scene_model, task_progress
from hardware.sim.tasks.cap_screw import CapScrew
from hardware.sim.tasks.peg_insert import PegInsert
from hardware.sim.tasks.press_fit import PressFit
from hardware.sim.tasks.tight_insert import TightInsert
from hardware.sim.tasks.wipe import Wipe

TASKS: dict[str, Task] = {t.name: t for t in (PegInsert(), Wipe(), PressFit(), TightInsert(), CapScrew())}


def get_task(name: str | Task | None) -> Task | None:
    """The task called `name` (None -> None; a Task passes through)."""
    if name is None or isinstance(name, Task):
        return name
    if name not in TASKS:
        raise ConfigError(f"unknown task {name!r}", where="--task / [twin] task",
                          fix=f"use one of {', '.join(sorted(TASKS))} (factr2 tasks lists them)")
    return TASKS[name]


__all__ = ["TASKS", "get_task", "Task", "StageTracker", "scene_model", "task_progress"]
