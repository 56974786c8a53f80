"""`factr2 tasks`: the contact-rich tasks of the twins, their stages and the arms whose scene holds them."""

from __future__ import annotations

HELP = "list the twin tasks (SIMULATED) with their stages (docs/tasks.md)"


def add_arguments(parser) -> None:
    pass


def run(args) -> int:
    from hardware.sim.tasks import TASKS

    for t in TASKS.values():
        print(f"{t.name:11s} {t.title}")
        print(f"{'':11s} stages: {' -> '.join(t.stages)}; arms: {', '.join(t.arms)}; "
              f"limit {t.episode_s:.0f} s per episode")
    print("collect demonstrations: factr2 collect --rig sim-piper --task NAME --episodes N --out DIR")
    return 0
