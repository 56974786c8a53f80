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


def test_the_simulated_hand_feels_the_arm_through_a_silent_chain_and_teleop_re_couples():
    """Half a second of silence: the hand on the leader keeps holding the arm (it feels the arm, not the
    driver's frozen sample), so the leader comes back where the follower held and the pair re-couples
    without the 'differ too much' refusal (the hand used to push at its clip on the frozen reading and fling
    the leader 1-3 rad)."""
    for t_s in (1.0, 2.3):  # (the demo script's own pace decides how far the hand takes the leader meanwhile)
        out = run_fault(f"dxl_unplug@{t_s}:0.5", seconds=4.0)
        assert out.recovered == [True]
        assert not said(out, "differ too much"), out.messages
        assert out.jumps_rejected == 0


def test_felt_joints_takes_the_twins_truth_only_where_the_reading_is_stale():
    import numpy as np

    from factr2_teleop.teleop.virtual_operator import felt_joints
    from hardware.types import STATUS_ENABLED, STATUS_STALE, JointState

    class Bank:
        def true_state(self):
            return np.array([10.0, 20.0, 30.0, 40.0]), np.array([1.0, 2.0, 3.0, 4.0])

    n = 3
    st = JointState(t=0.0, q=np.array([0.1, 0.2, 0.3]), q_dot=np.array([np.nan, 0.5, 0.6]), tau_m=np.zeros(n),
                    current=np.zeros(n), q_cmd=np.zeros(n), temperature=np.zeros(n),
                    status=np.full(n, STATUS_ENABLED, np.uint32))
    q, qd = felt_joints(st, Bank())
    np.testing.assert_array_equal(q, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(qd, [0.0, 0.5, 0.6])
    st.status[1] |= np.uint32(STATUS_STALE)
    q, qd = felt_joints(st, Bank())
    np.testing.assert_array_equal(q, [0.1, 20.0, 0.3])
    np.testing.assert_array_equal(qd, [0.0, 2.0, 0.6])
