"""The teleop loop over in-test IdealMotorBank fakes on a lockstep clock: start, faults, stop, timing."""

from __future__ import annotations

import numpy as np
import pytest
from teleop_fakes import Rig, no_model_cfg

from calibration.estimators import GroundTruthEstimator
from factr2_teleop.teleop.loop import TeleopLoop
from factr2_teleop.teleop.pair import COUPLED, FAULT, HOLD, SOFT_START, STOPPED
from factr2_teleop.teleop.soft_start import SoftStart, SoftStartConfig, mismatch_error, rate_limit
from factr2_teleop.teleop.timing import LoopTiming
from hardware.errors import UserError


def fb_cfg(**kw):
    cfg = no_model_cfg(**kw)
    cfg.law.feedback.gain = 0.5
    cfg.law.feedback.t_high_nm = 0.3
    cfg.law.feedback.t_low_nm = 0.1
    cfg.law.feedback.clip_nm = 3.0
    cfg.law.damping_kd = 0.02
    return cfg


def assert_safe(rig):
    assert rig.leader.sent[-1].tau.tolist() == [0.0] * rig.lb.n
    assert rig.follower.sent[-1].hold


# -- soft start ---------------------------------------------------------------------------------------
def test_soft_start_refuses_large_mismatch_with_per_joint_message():
    err = mismatch_error(np.array([0.0, 0.0, 0.0]), np.array([0.2, -1.4, 1.3]), np.full(3, 1.0), where="left")
    assert isinstance(err, UserError)
    assert "j2 1.40 rad" in str(err) and "j3 1.30 rad" in str(err) and "j1" not in str(err)
    # an unread (NaN) joint counts as too far
    assert mismatch_error(np.zeros(3), np.array([0.9, -0.9, np.nan]), np.full(3, 1.0)) is not None
    assert mismatch_error(np.zeros(3), np.array([0.9, -0.9, 0.0]), np.full(3, 1.0)) is None
    rig = Rig(q_leader=[0.0, 1.5, 0.0], q_follower=[0.0, 0.0, 0.0])
    loop = TeleopLoop([rig.pair()], rig.clock)
    with pytest.raises(UserError, match="j2 1.50 rad"):
        loop.run(max_ticks=10)
    assert_safe(rig)
    assert rig.fb.q[1] == pytest.approx(0.0, abs=1e-6)  # the follower never moved


def test_soft_start_survives_ruckig_rejecting_its_input():
    """ruckig raised RuckigError (not a RuntimeError) on a joint at exactly v_max in the fault campaign's
    collect sessions, and the collection ended with it: now retried inside the limits, then from rest."""
    import ruckig

    s = SoftStart(SoftStartConfig(v_max_rad_s=0.5, a_max_rad_s2=2.0, j_max_rad_s3=10.0), 2, 0.002)
    s.reset(np.zeros(2))
    for _ in range(50):
        s.step(np.array([1.0, -1.0]))
    real, calls = s._otg, []

    class Rejecting:  # rejects the first n inputs it is given, then plans as ruckig does
        def __init__(self, n):
            self.n = n

        def update(self, inp, out):
            calls.append(list(inp.current_velocity))
            if len(calls) <= self.n:
                raise ruckig.RuckigError("[ruckig] error in step 2 in dof: 0 for t sync")
            return real.update(inp, out)

    q_before = s.q.copy()
    s._otg = Rejecting(1)
    q, _ = s.step(np.array([1.0, -1.0]))
    assert np.all(np.abs(calls[1]) <= 0.99 * 0.5 + 1e-12)  # retried just inside the velocity limit
    assert np.all(np.abs(q - q_before) <= 0.5 * 0.002 + 1e-9)  # and moved on from where it was
    calls.clear()
    s._otg = Rejecting(2)
    q, _ = s.step(np.array([1.0, -1.0]))
    assert calls[2] == [0.0, 0.0]  # then from rest at the last target
    calls.clear()
    s._otg = Rejecting(3)
    q2, done = s.step(np.array([1.0, -1.0]))
    assert np.array_equal(q2, q) and not done  # still rejected: the last target is kept, no exception


def test_soft_start_ruckig_ramps_within_limits():
    s = SoftStart(SoftStartConfig(v_max_rad_s=0.5, a_max_rad_s2=2.0, j_max_rad_s3=20.0), 2, 0.002)
    s.reset(np.zeros(2))
    traj, done = [], False
    for _ in range(2000):
        q, done = s.step(np.array([0.6, -0.3]))
        traj.append(q)
        if done:
            break
    traj = np.array(traj)
    v = np.diff(traj, axis=0) / 0.002
    assert done and np.allclose(traj[-1], [0.6, -0.3], atol=0.02)
    assert np.max(np.abs(v)) <= 0.5 + 1e-6 and np.max(np.abs(np.diff(v, axis=0) / 0.002)) <= 2.0 + 1e-3
    assert len(traj) * 0.002 > 0.6 / 0.5  # no faster than v_max allows
    assert np.allclose(rate_limit(np.array([1.0, -1.0, np.nan]), np.zeros(3), np.full(3, 2.0), 0.01),
                       [0.02, -0.02, 0.0])


def test_loop_soft_starts_small_mismatch_then_couples_and_tracks():
    rig = Rig(q_leader=[0.3, -0.4, 0.2], q_follower=[0.0, 0.0, 0.0])
    pair = rig.pair()
    phases = []
    loop = TeleopLoop([pair], rig.clock, recorder=lambda r: phases.append((r.t, r.phase)))
    loop.run(duration_s=3.0)
    ph = [p for _, p in phases]
    assert ph[0] == SOFT_START and COUPLED in ph
    t_coupled = next(t for t, p in phases if p == COUPLED)
    assert t_coupled > 0.4 / 0.5  # the ruckig move at 0.5 rad/s took its time
    assert np.allclose(rig.fb.q, rig.lb.q, atol=0.02)
    assert_safe(rig)  # run() ended: leader zero torque, follower hold
    assert loop.snapshot().phases["arm"] == STOPPED


# -- faults -------------------------------------------------------------------------------------------
def test_follower_holds_within_50ms_of_leader_silence():
    rig = Rig()
    pair = rig.pair()
    loop = TeleopLoop([pair], rig.clock)
    events = []

    def rec(r):
        events.append((r.t, r.phase))
        if r.t >= 1.0 and not rig.leader.silent:
            rig.leader.silent = True  # the leader stops answering at t = 1.0 s (last sample at ~1.0 s)

    loop.recorder = rec
    loop.run(duration_s=1.2)
    n_before = sum(1 for s in rig.follower.sent if s.hold)
    t_hold = next(t for t, p in events if p == HOLD and t > 1.0)
    assert t_hold - 1.0 <= 0.05
    holds = [s for s in rig.follower.sent if s.hold]
    assert n_before >= 2 and holds  # the hold during the loop, and the final one
    assert any("leader data stale" in m for _, _, m in loop.snapshot().messages)


def test_leader_back_after_silence_resumes_through_soft_start():
    rig = Rig()
    pair = rig.pair()
    pair.cfg.soft_start.resume_direct_rad = 0.0  # always through the soft start (default: direct when close)
    loop = TeleopLoop([pair], rig.clock)
    seen = []

    def rec(r):
        seen.append(r.phase)
        rig.leader.silent = 0.5 <= r.t < 0.7

    loop.recorder = rec
    loop.run(duration_s=1.5)
    i_hold = seen.index(HOLD)
    assert seen[-1] == COUPLED and COUPLED in seen[:i_hold]
    msgs = [m for _, _, m in loop.snapshot().messages]
    assert msgs.count("coupled: follower tracks the leader") == 2  # again through the soft start


def test_nan_estimate_turns_feedback_off_with_message():
    rig = Rig()
    state = {"nan": False}

    def truth():
        return np.array([np.nan, 0.0, 0.0]) if state["nan"] else np.array([0.0, -1.0, 0.0])

    pair = rig.pair(fb_cfg(), estimator=GroundTruthEstimator(truth))
    gates = []

    def rec(r):
        gates.append((r.t, r.gate, r.tau_feedback.copy()))
        state["nan"] = r.t >= 1.0

    loop = TeleopLoop([pair], rig.clock, recorder=rec)
    loop.run(duration_s=1.2)
    before = [g for t, g, _ in gates if 0.9 < t < 1.0]
    after = [(g, tf) for t, g, tf in gates if t > 1.003]
    assert min(before) == 1.0
    assert all(g == 0.0 and np.all(tf == 0.0) for g, tf in after)
    assert sum("non-finite" in m for _, _, m in loop.snapshot().messages) == 1


def test_exception_in_a_tick_leaves_both_arms_safe_and_is_reraised():
    rig = Rig()
    pair = rig.pair()

    def boom(r):
        if r.t > 0.5:
            raise RuntimeError("driver exploded")

    orig_tick = pair.tick

    def tick(now):
        rec = orig_tick(now)
        boom(rec)
        return rec

    pair.tick = tick
    loop = TeleopLoop([pair], rig.clock)
    with pytest.raises(RuntimeError, match="exploded"):
        loop.run(duration_s=2.0)
    assert_safe(rig)
    snap = loop.snapshot()
    assert snap.phases["arm"] == FAULT and "exploded" in snap.error and not snap.running


def test_stop_request_and_keyboard_interrupt_leave_both_safe():
    rig = Rig()
    loop = TeleopLoop([rig.pair()], rig.clock)

    def rec(r):
        if r.t > 0.3:
            loop.stop()  # the loop thread itself asks (UI button); run() returns at the next check

    loop.recorder = rec
    loop.run(duration_s=5.0)
    assert rig.clock.now() < 0.4
    assert_safe(rig)

    rig2 = Rig()
    loop2 = TeleopLoop([rig2.pair()], rig2.clock)

    # Ctrl-C lands wherever the loop is; here inside clock.sleep (recorder exceptions are swallowed)
    rig2.clock.attach(lambda t: (_ for _ in ()).throw(KeyboardInterrupt()) if t > 0.2 else None)
    with pytest.raises(KeyboardInterrupt):
        loop2.run(duration_s=5.0)
    assert_safe(rig2)
    assert loop2.snapshot().phases["arm"] == STOPPED


def test_recorder_failure_stops_recording_not_the_arms():
    rig = Rig()

    def bad(r):
        raise OSError("disk full")

    loop = TeleopLoop([rig.pair()], rig.clock, recorder=bad)
    loop.run(duration_s=0.3)
    assert loop.recorder is None and loop.recorder_errors == 1
    assert any("disk full" in m for _, _, m in loop.snapshot().messages)
    assert loop.timing.ticks >= 140


def test_bimanual_two_pairs_one_loop():
    a, b = Rig(), Rig()
    b.clock = a.clock  # one lockstep clock drives both benches
    b.leader.clock = b.follower.clock = a.clock
    a.clock.attach(b._advance)
    pa = a.pair(no_model_cfg(name="left"))
    pb = b.pair(no_model_cfg(name="right"))
    loop = TeleopLoop([pa, pb], a.clock)
    loop.run(duration_s=1.0)
    snap = loop.snapshot()
    assert set(snap.records) == {"left", "right"} and snap.records["right"].pair == "right"
    with pytest.raises(ValueError):
        TeleopLoop([pa, pa], a.clock)


# -- timing -------------------------------------------------------------------------------------------
def test_timing_stats_ring_buffer():
    tm = LoopTiming(500.0, capacity=100)
    t = 0.0
    for i in range(250):
        t += 0.004 if i == 200 else 0.002  # one 4 ms gap (an overrun at 1.5x)
        tm.record(t, 0.0005)
    s = tm.stats()
    assert s.ticks == 250 and s.overruns == 1
    assert s.period_p50_ms == pytest.approx(2.0) and s.period_max_ms == pytest.approx(4.0)
    assert s.rate_hz == pytest.approx(1.0 / np.mean([0.002] * 99 + [0.004]))
    assert s.compute_p99_ms == pytest.approx(0.5)
    assert "Hz" in s.line()
    assert np.isnan(LoopTiming(500.0).stats().rate_hz)
    assert np.isnan(s.cpu_mean_ms) and "loop CPU" not in s.line()  # not measured: not shown


def test_timing_reports_the_loop_threads_cpu_as_a_share_of_the_period():
    tm = LoopTiming(500.0, capacity=100)
    for i in range(150):
        tm.record(0.002 * i, 0.0015, 0.0004 if i % 2 else 0.0006)  # 0.5 ms mean of a 2 ms period
    s = tm.stats()
    assert s.cpu_mean_ms == pytest.approx(0.5) and s.cpu_share == pytest.approx(0.25)
    assert s.cpu_p99_ms == pytest.approx(0.6)
    assert "loop CPU 0.50 ms/tick (25 % of the period)" in s.line()


def test_loop_timing_on_lockstep_clock_is_exact():
    rig = Rig()
    loop = TeleopLoop([rig.pair()], rig.clock, rate_hz=250.0)
    loop.run(duration_s=1.0)
    s = loop.snapshot().timing
    assert s.rate_hz == pytest.approx(250.0) and s.overruns == 0 and s.ticks == 250
    rec = loop.snapshot().records["arm"]
    assert rec.loop_period_s == pytest.approx(0.004) and rec.loop_overruns == 0


def test_loop_makes_up_a_late_tick_but_not_a_long_stall():
    """A tick that ends 7 ms late is made up (back-to-back ticks keep the average rate: 500 ticks in 1 s);
    after a 50 ms stall (beyond CATCH_UP_S) the schedule restarts from now and those ticks are lost."""
    from factr2_teleop.teleop.loop import CATCH_UP_S

    assert 0.007 < CATCH_UP_S < 0.05
    for stall_s, made_up in ((0.007, True), (0.05, False)):
        rig = Rig()
        pair = rig.pair()
        tick, count = pair.tick, [0]

        def slow_tick(now, tick=tick, count=count, rig=rig, stall_s=stall_s):
            count[0] += 1
            rec = tick(now)
            if count[0] == 100:
                rig.clock.sleep(stall_s)  # this tick took stall_s longer
            return rec

        pair.tick = slow_tick
        loop = TeleopLoop([pair], rig.clock, rate_hz=500.0)
        loop.run(duration_s=1.0)
        s = loop.snapshot().timing
        assert s.overruns == 1
        if made_up:
            assert s.ticks == 500 and s.rate_hz == pytest.approx(500.0, rel=1e-6)
        else:
            assert 470 <= s.ticks <= 477  # ~stall_s x 500 ticks lost


def test_threaded_loop_on_real_clock_stops_safe():
    """start() in a thread on the real clock; stop() from this thread leaves both arms safe."""
    import time

    from teleop_fakes import BankFollower, BankLeader

    from factr2_teleop.teleop.pair import ArmPair
    from hardware.clock import Clock
    from hardware.sim.motors import IdealMotorBank

    clock = Clock()

    class WallBank(IdealMotorBank):  # advances to wall time on every read (the loop thread drives it)
        def __init__(self, **kw):
            super().__init__(3, dt_s=1e-3, **kw)
            self.t = clock.now()

        def read(self):
            self.advance(clock.now())
            return super().read()

    lead, fol = BankLeader(WallBank(), clock), BankFollower(WallBank(kp_fw=200.0, kd_fw=3.0), clock)
    lead.connect()
    fol.connect()
    loop = TeleopLoop([ArmPair(lead, fol, no_model_cfg(), 1 / 200)], clock, rate_hz=200.0)
    th = loop.start()
    time.sleep(0.3)
    assert loop.running and th.is_alive()
    loop.stop(timeout_s=2.0)
    assert not th.is_alive() and not loop.running
    assert lead.sent[-1].tau.tolist() == [0.0] * 3 and fol.sent[-1].hold
    assert loop.snapshot().timing.ticks > 10 and loop.error is None


def test_leader_back_after_short_silence_recouples_directly_when_close():
    rig = Rig()
    pair = rig.pair()
    loop = TeleopLoop([pair], rig.clock)
    seen = []

    def rec(r):
        seen.append(r.phase)
        rig.leader.silent = 0.5 <= r.t < 0.55

    loop.recorder = rec
    loop.run(duration_s=1.0)
    i_hold = seen.index(HOLD)
    assert SOFT_START not in seen[i_hold:] and seen[-1] == COUPLED
    assert "re-coupled after hold" in [m for _, _, m in loop.snapshot().messages]


def test_a_stopped_app_recouples_through_the_soft_start():
    rig = Rig()
    pair = rig.pair()  # default resume_direct_rad: a short hold close to the leader would re-couple at once
    loop = TeleopLoop([pair], rig.clock)
    seen = []

    def rec(r):
        seen.append(r.phase)
        if len(seen) == 250:
            rig.clock.sleep(2.0)  # the whole app stops for 2 s (SIGSTOP): its next tick comes 2 s late

    loop.recorder = rec
    loop.run(duration_s=4.0)
    msgs = [m for _, _, m in loop.snapshot().messages]
    assert any(m.startswith("follower on hold: the loop did not run for 2") for m in msgs), msgs
    assert "re-coupled after hold" not in msgs
    assert msgs.count("coupled: follower tracks the leader") == 2 and seen[-1] == COUPLED
