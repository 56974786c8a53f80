"""Shared checks of the fault tests (tests/test_faults_*.py): one seeded lockstep twin run per fault."""

from __future__ import annotations

from factr2_teleop.demo.fault_run import FaultOutcome, run_with_faults
from hardware.sim.faults import parse_fault

WATCHDOG_MS = 50.0  # ms: one watchdog period (hardware.safety.DEFAULT_WATCHDOG_S)


def run_fault(text: str, seconds: float = 2.5) -> FaultOutcome:
    """One fault KIND@T[:DURATION] in a lockstep teleop run; asserts what every fault must leave: no error,
    no command outside the limits, both arms safe at the end, the twin's log says it injected it."""
    out = run_with_faults([parse_fault(text)], seconds=seconds)
    assert out.error is None, out.error
    assert out.violations == 0
    assert out.safe_at_end
    assert out.log and out.log[0]["event"] == "start" and out.log[0]["kind"] == text.split("@")[0]
    return out


def said(out: FaultOutcome, text: str) -> bool:
    return any(text in m[2] for m in out.messages)
