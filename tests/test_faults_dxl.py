"""SIMULATED Dynamixel faults on the sim-piper twin's leader (lockstep, seeded)."""

from __future__ import annotations

from tests.fault_helpers import WATCHDOG_MS, run_fault, said


def test_unplugged_leader_holds_the_follower_and_resumes_when_it_answers_again():
    out = run_fault("dxl_unplug@0.8:0.3")
    assert out.safe_ms[0] is not None and out.safe_ms[0] <= WATCHDOG_MS
    assert said(out, "follower on hold: leader data stale")
    assert out.recovered == [True]


def test_overload_bit_holds_the_follower_and_says_so():
    out = run_fault("dxl_overload@0.8")
    assert out.safe_ms[0] is not None and out.safe_ms[0] <= WATCHDOG_MS
    assert said(out, "leader motor error: j2 driver/encoder error")


def test_corrupted_packet_storm_stays_within_limits():
    out = run_fault("dxl_corrupt@0.8:0.3")
    assert out.recovered == [True]
