"""`factr2 collect`: scripted demonstrations of a twin task through the full teleop stack (SIMULATED),
lockstep (faster than real time), one MCAP per run (docs/tasks.md)."""

from __future__ import annotations

import sys

from factr2_teleop.commands._twin_fault import add_twin_fault_argument, twin_faults

HELP = "collect scripted demonstrations of a twin task through the leader, force feedback and recording"


def add_arguments(parser) -> None:
    parser.add_argument("--rig", default="sim-piper", help="a simulated rig (default: sim-piper)")
    parser.add_argument("--task", required=True, help="task name (factr2 tasks lists them)")
    parser.add_argument("--episodes", type=int, default=10, help="demonstrations to collect (default 10)")
    parser.add_argument("--out", required=True, help="folder for the run's MCAP and summary JSON")
    parser.add_argument("--seed", type=int, default=0, help="seed of the initial conditions (default 0)")
    parser.add_argument("--mode", default=None, help="feedback mode (default: next with a checkpoint, "
                        "else dob; see factr2 teleop --help)")
    parser.add_argument("--checkpoint", default=None, help="NEXT checkpoint (next.json from factr2 calibrate;"
                        " default: the rig's, else the demo's cache)")
    parser.add_argument("--no-cameras", action="store_true", help="record no camera frames (faster)")
    see = parser.add_mutually_exclusive_group()
    see.add_argument("--perception", dest="perception", action="store_true", default=None,
                     help="the operator sees the objects through the simulated camera pose detector "
                     "(bias, noise, latency, occlusion: docs/perception.md), not the twin's truth "
                     "(default: the task's choice; peg-insert, press-fit and wipe see the truth)")
    see.add_argument("--no-perception", dest="perception", action="store_false",
                     help="the operator sees the twin's truth")
    from factr2_teleop.teleop.perturb import PerturbConfig

    defaults = ", ".join(f"{k}={v:g}" for k, v in PerturbConfig().to_dict().items() if k != "joints")
    parser.add_argument("--perturb", nargs="?", const="on", default=None, metavar="KEY=VALUE,...",
                        help="teach recovery (DART-style): small smooth offsets on the follower's target in "
                        "windows drawn per episode, which the operator corrects; marked in the recording "
                        f"(factr2 train --perturbed). Settings over the defaults: {defaults}, joints=0+1+2 "
                        "(default all; docs/tasks.md)")
    add_twin_fault_argument(parser)


def run(args) -> int:
    from factr2_teleop.tasks.run import CollectConfig, collect, summary_lines
    from factr2_teleop.teleop.perturb import parse_perturb

    cfg = CollectConfig(rig=args.rig, task=args.task, episodes=args.episodes, out=args.out, seed=args.seed,
                        mode=args.mode, checkpoint=args.checkpoint, cameras=not args.no_cameras,
                        faults=twin_faults(args), perception=args.perception,
                        perturb=parse_perturb(args.perturb) if args.perturb is not None else None)
    result = collect(cfg, progress=sys.stderr.isatty() or True)
    for line in summary_lines(result):
        print(line)
    return 0
