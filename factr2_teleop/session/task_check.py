"""Whether a trained policy is rolled out on the task its demonstrations came from.

A policy trained on wipe demonstrations does not insert a peg: rolling it out on peg-insert only measures a
failure, so the rollout refuses unless forced (`factr2 rollout --force`, the app's key f), and a forced
rollout says so. The run's meta lists the demonstrations' tasks (`tasks`: name -> episodes, written by
policies.training.run); runs from before that, and demonstrations without a twin task name (teleop of your own
task), are not checked: there is nothing to compare with.
"""

from __future__ import annotations

from hardware.errors import UserError


def trained_tasks(meta: dict) -> list[str]:
    """The twin tasks the run's demonstrations came from (names `factr2 tasks` lists), sorted."""
    from hardware.sim.tasks import TASKS

    return sorted(t for t in (meta.get("tasks") or {}) if t in TASKS)


def task_mismatch(meta: dict, task: str | None) -> str:
    """"" when the task is one the policy was trained on (or nothing can be compared), else what differs."""
    trained = trained_tasks(meta)
    if not task or not trained or task in trained:
        return ""
    return f"the policy was trained on {' and '.join(trained)} demonstrations, not {task}"


def check_task(meta: dict, task: str | None, force: bool = False) -> str:
    """The rollout's start: UserError for a task the policy was not trained on, unless forced; a forced
    mismatch returns the line to show ("" otherwise)."""
    why = task_mismatch(meta, task)
    if why and not force:
        ok = trained_tasks(meta)[0]
        raise UserError(why, where="--task", fix=f"pass --task {ok}, or --force to roll out on {task} anyway")
    return f"{why} (forced)" if why else ""
