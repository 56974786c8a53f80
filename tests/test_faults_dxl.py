"""SIMULATED Dynamixel faults on the sim-piper twin's leader (lockstep, seeded)."""

from __future__ import annotations

from tests.fault_helpers import WATCHDOG_MS, run_fault, said


def test_unplugged_leader_holds_the_follower_and_resumes_when_it_answers_again():
    out = run_fault("dxl_unplug@0.8:0.3")
    assert out.safe_ms[0] is not None and out.safe_ms[0] <= WATCHDOG_MS
    assert said(out, "follower on hold: leader data stale")
    assert out.recovered == [True]


def test_overload_bit_holds_the_follower_then_the_servo_is_rebooted_and_teleop_resumes():
    out = run_fault("dxl_overload@0.8", seconds=3.0)
    assert out.safe_ms[0] is not None and out.safe_ms[0] <= WATCHDOG_MS
    assert said(out, "leader motor error: j2 driver/encoder error")
    notes = " | ".join(out.device_notes)
    assert "hardware alert (overload)" in notes and "rebooted" in notes and "back after its reboot" in notes
    assert out.recovered == [True] and said(out, "re-coupled after hold")


def test_corrupted_packet_storm_stays_within_limits():
    out = run_fault("dxl_corrupt@0.8:0.3")
    assert out.recovered == [True]
