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


def test_damiao_motor_error_holds_and_a_kind_the_rig_cannot_play_is_refused():
    from factr2_teleop.demo.fault_run import run_with_faults
    from hardware.errors import ConfigError
    from hardware.sim.faults import parse_fault

    out = run_with_faults([parse_fault("motor_overtemp@0.8:0.4")], seconds=2.0, rig="sim-yam")
    assert out.error is None and out.violations == 0 and out.safe_at_end
    assert out.safe_ms[0] is not None and out.safe_ms[0] <= WATCHDOG_MS and out.recovered == [True]
    assert said(out, "follower motor error: j2 over-temperature")
    with pytest.raises(ConfigError, match="cannot be played on this rig"):  # sim-panda: no CAN follower
        run_with_faults([parse_fault("can_busoff@0.8")], seconds=1.0, rig="sim-panda")


def test_data_age_at_the_hold_is_the_reaction_a_partial_fault_owes():
    """can_loss drops half the frames: the hold comes when a gap first exceeds the staleness limit, not at the
    fault's start; the age of the data at the hold stays within one watchdog period."""
    import numpy as np

    from factr2_teleop.demo.fault_run import data_age_ms

    out = run_fault("can_loss@0.8:0.4")  # (seeded: its first gap over the limit opens 30 ms in)
    assert out.safe_ms[0] > WATCHDOG_MS and out.stale_ms[0] <= WATCHDOG_MS, (out.safe_ms, out.stale_ms)
    # the pure function: at the last tick up to the hold, the hold time minus the oldest sample used
    t = np.array([0.0, 0.002, 0.004, 0.006])
    samples = np.array([[0.0, 0.0], [0.002, 0.002], [0.002, 0.004], [0.002, 0.006]])
    assert data_age_ms(0.006, t, samples) == 4.0
    assert data_age_ms(0.005, t, samples) == 3.0
    assert data_age_ms(None, t, samples) is None and data_age_ms(-1.0, t, samples) is None


def test_fresh_times_keep_the_last_all_fresh_sample_of_each_device():
    """A partial Dynamixel read is stamped when it was read, its unanswered joints flagged stale: the data's
    age counts from the last sample with every joint fresh."""
    from types import SimpleNamespace as NS

    import numpy as np

    from factr2_teleop.demo.fault_run import fresh_times
    from hardware.types import STATUS_ENABLED, STATUS_STALE

    ok, stale = np.full(3, STATUS_ENABLED, np.uint32), np.array([STATUS_ENABLED, STATUS_STALE, 0], np.uint32)
    prev = fresh_times(None, NS(t=1.0, status=ok), NS(t=1.0, status=ok))
    assert prev == (1.0, 1.0)
    prev = fresh_times(prev, NS(t=1.002, status=ok), NS(t=1.002, status=stale))
    assert prev == (1.002, 1.0)
    assert fresh_times(prev, NS(t=1.004, status=ok), NS(t=1.004, status=ok)) == (1.004, 1.004)
