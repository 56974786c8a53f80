"""--twin-fault KIND@T[:DURATION] (repeatable), one option for every command that runs a twin (teleop,
collect, rollout): the faults the twin plays (hardware/sim/faults.py, docs/safety.md)."""

from __future__ import annotations


def add_twin_fault_argument(p) -> None:
    p.add_argument("--twin-fault", action="append", metavar="KIND@T[:DURATION]",
                   help="a fault the twin plays at T s for DURATION s (repeatable; simulated rigs; kinds: "
                        "docs/safety.md)")


def twin_faults(args) -> list | None:
    """The FaultSpecs of --twin-fault (None: none given, the rig's [twin] faults apply).
    ConfigError (one line) on a bad one."""
    from hardware.sim.faults import parse_fault

    given = getattr(args, "twin_fault", None)
    return [parse_fault(x) for x in given] if given else None

