"""SIMULATED CAN faults on the sim-piper twin's follower (lockstep, seeded): the follower holds within one
watchdog period, says why, and re-couples without a restart once the bus / motor is back."""

from __future__ import annotations

import pytest

from tests.fault_helpers import WATCHDOG_MS, run_fault, said


def test_bus_off_holds_within_a_watchdog_period_and_recovers():
    out = run_fault("can_busoff@0.8:0.3")
    assert out.safe_ms[0] is not None and out.safe_ms[0] <= WATCHDOG_MS
    assert said(out, "follower on hold: follower data stale") and said(out, "re-coupled after hold")
    assert out.recovered == [True]


def test_frame_loss_burst_stays_within_limits_and_recovers():
    out = run_fault("can_loss@0.8:0.3")
    assert out.recovered == [True]


@pytest.mark.parametrize("kind,what", [("motor_overcurrent", "j2 over-current"),
                                       ("motor_overtemp", "j2 over-temperature"),
                                       ("motor_encoder", "j2 driver/encoder error")])
def test_motor_error_holds_the_follower_and_says_which(kind, what):
    out = run_fault(f"{kind}@0.8:0.4")
    assert out.safe_ms[0] is not None and out.safe_ms[0] <= WATCHDOG_MS  # low-speed frames come at 40 Hz
    assert said(out, f"follower motor error: {what}")
