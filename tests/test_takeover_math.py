"""Operator takeover (issue #33), the pure math: the hand detector (threshold, hysteresis, minimum duration,
hand at rest), the following spring and its caps, and the follower target across random takeovers and
hand-backs, which never steps beyond one teleop tick's motion (hypothesis)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from factr2_teleop.teleop.soft_start import SoftStartConfig
from factr2_teleop.teleop.takeover import (
    HANDBACK,
    OPERATOR,
    POLICY,
    TAKEOVER,
    DetectorState,
    TakeoverConfig,
    blend_gripper,
    blend_weight,
    detect_step,
    follow_torque,
    hand_baseline_step,
    hand_torque_nm,
    handover_target,
    lag_allowance,
    leader_goal,
    spring_torque_nm,
)

DT = 1 / 500.0
CFG = TakeoverConfig()
V_MAX = SoftStartConfig().rate_limit_rad_s  # rad/s: teleop's coupled-phase rate limit
TICK_STEP = V_MAX * DT  # rad: what one tick of teleop moves the target at most


def _run(hand, cfg=CFG):
    """Detector over a hand-torque series [N*m] at 500 Hz (the leader still): events with their tick."""
    stt, out = DetectorState(), []
    for k, h in enumerate(hand):
        stt, ev = detect_step(stt, k * DT, float(h), np.zeros(3), cfg)
        if ev:
            out.append((k, ev))
    return out


def test_a_grab_needs_the_threshold_for_the_minimum_duration():
    n_min = round(CFG.grab_min_s / DT)
    short = np.r_[np.zeros(10), np.full(n_min - 2, CFG.grab_nm + 0.1), np.zeros(10)]
    assert _run(short) == []  # a bump shorter than grab_min_s is not a grab
    long = np.r_[np.zeros(10), np.full(n_min + 5, CFG.grab_nm + 0.1)]
    assert _run(long) == [(10 + n_min, TAKEOVER)]  # exactly grab_min_s after it crossed


def test_hysteresis_keeps_timing_between_release_and_grab():
    mid = 0.5 * (CFG.grab_nm + CFG.release_nm)
    n_min = round(CFG.grab_min_s / DT)
    # crosses grab once, then stays between the thresholds: still a grab
    hand = np.r_[np.zeros(5), CFG.grab_nm, np.full(n_min + 5, mid)]
    assert _run(hand) == [(5 + n_min, TAKEOVER)]
    # between the thresholds without ever reaching grab: nothing
    assert _run(np.full(4 * n_min, mid)) == []
    # dips below release restart the timer
    dip = np.r_[np.full(n_min - 3, CFG.grab_nm), 0.0]
    assert _run(np.tile(dip, 6)) == []


def test_hand_back_needs_the_hand_at_rest_for_rest_s():
    n_rest = round(CFG.rest_s / DT)
    stt = DetectorState(OPERATOR)
    events = []
    # the leader moves (1 rad/s) for a while, then stands still but for a chatter far below rest_tol_rad
    for k in range(3 * n_rest):
        q = np.full(3, min(k, n_rest) * DT * 1.0) + 1e-3 * (-1) ** k
        stt, ev = detect_step(stt, k * DT, 0.0, q, CFG)
        if ev:
            events.append((k, ev))
            break
    assert len(events) == 1 and events[0][1] == HANDBACK
    assert abs(events[0][0] - 2 * n_rest) <= 16  # tol / step
    # a hand still pushing (torque above release) is not at rest
    stt, evs = DetectorState(OPERATOR), []
    for k in range(3 * n_rest):
        stt, ev = detect_step(stt, k * DT, CFG.release_nm + 0.05, np.zeros(3), CFG)
        evs.append(ev)
    assert evs == [None] * (3 * n_rest)


def test_following_torque_is_capped_and_has_no_spring_on_unmapped_joints():
    q = np.zeros(3)
    goal = leader_goal(np.array([1.0, np.nan, -1.0]), q)
    assert goal[1] == q[1]  # an unmapped leader joint is its own goal
    cap = np.array([0.5, 0.5, 0.2])
    tau = follow_torque(q, np.zeros(3), goal, np.zeros(3), np.full(3, 2.0), np.full(3, 0.1), np.zeros(3), cap)
    assert np.array_equal(tau, [0.5, 0.0, -0.2])
    tau = follow_torque(q, np.array([np.nan, 0, 0]), np.full(3, np.nan), np.zeros(3), 2.0, 0.1, 0.0, cap)
    assert np.all(np.isfinite(tau)) and np.all(tau == 0.0)


def test_hand_torque_discounts_the_lag_behind_a_moving_follower_and_the_leaders_load():
    kp, lag = np.full(2, 2.0), np.full(2, 0.15)
    spring = spring_torque_nm(np.zeros(2), np.array([0.2, 0.0]), kp)
    zero = np.zeros(2)
    assert hand_torque_nm(spring, zero, zero, zero) == pytest.approx(0.4)
    # the same gap behind a follower moving at 2 rad/s is mostly lag
    moving = np.array([2.0, 0.0])
    allow = lag_allowance(zero, moving, lag, 0.002, 0.5)
    assert hand_torque_nm(spring, zero, allow, moving) == pytest.approx(0.1)
    # ... and stays lag for a while after the follower stopped: the allowance decays over hold_s
    allow_later = lag_allowance(allow, zero, lag, 0.25, 0.5)
    assert allow_later[0] == pytest.approx(0.3 * np.exp(-0.5))
    assert hand_torque_nm(spring, zero, allow_later, zero) == pytest.approx(0.4 - 0.3 * np.exp(-0.5))
    # a steady load the spring holds (the leader's gravity residual) is the baseline, not a hand
    assert hand_torque_nm(spring, spring, zero, zero) == 0.0
    assert hand_torque_nm(spring_torque_nm(np.full(2, np.nan), zero, kp), zero, zero, zero) == 0.0
    # faster than grab_max_speed_rad_s: not sensed at all (the key takes over then)
    assert hand_torque_nm(spring_torque_nm(zero, np.array([0.9, 0.0]), kp), zero, zero,
                          np.array([1.6, 0.0]), 1.5) == 0.0


def test_hand_baseline_follows_a_slow_load_and_keeps_through_a_missing_reading():
    b = np.zeros(2)
    for _ in range(2000):  # 4 s at 2 ms of a steady 0.3 N*m on joint 0: the baseline converges (tau 0.7 s)
        b = hand_baseline_step(b, np.array([0.3, 0.0]), 0.002, 0.7)
    np.testing.assert_allclose(b, [0.3, 0.0], atol=1e-3)
    b2 = hand_baseline_step(b, np.array([np.nan, 1.0]), 0.002, 0.7)
    assert b2[0] == b[0] and 0.0 < b2[1] < 0.01


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_switch=st.integers(1, 8), blend=st.floats(0.0, 0.5),
       gap=st.floats(0.0, 1.5))
def test_random_takeovers_and_hand_backs_never_step_beyond_one_teleop_tick(seed, n_switch, blend, gap):
    """Two sources (a policy's target and a leader's pose, apart by up to `gap` rad and each moving at up
    to twice teleop's rate), switched at random ticks: the follower target never moves more than
    rate_limit_rad_s * dt in a tick, and after each switch's blend it is on the new source."""
    rng = np.random.default_rng(seed)
    n, nj = 600, 6
    t = np.arange(n) * DT
    drift = np.cumsum(rng.uniform(-2 * TICK_STEP, 2 * TICK_STEP, (n, nj)), axis=0)
    policy = drift + 0.1 * np.sin(2 * np.pi * rng.uniform(0.2, 2.0) * t)[:, None]
    leader = policy + gap * rng.uniform(-1, 1, nj) + np.cumsum(rng.normal(0, TICK_STEP, (n, nj)), axis=0)
    switches = set(rng.choice(np.arange(1, n), size=n_switch, replace=False).tolist())
    src, t_sw = POLICY, -math.inf
    q_prev, offset = policy[0].copy(), np.zeros(nj)
    g_cmd, g_off = 0.04, 0.0
    for k in range(n):
        if k in switches:
            src, t_sw = (OPERATOR if src == POLICY else POLICY), t[k]
            new = leader[k] if src == OPERATOR else policy[k]
            offset = q_prev - new
            g_off = g_cmd - (0.0 if src == OPERATOR else 0.04)
        q_src = leader[k] if src == OPERATOR else policy[k]
        w = blend_weight(t[k] - t_sw, blend)
        q = handover_target(q_src, offset, w, q_prev, V_MAX, DT)
        assert np.all(np.abs(q - q_prev) <= TICK_STEP * (1 + 1e-12) + 1e-15), (k, np.abs(q - q_prev).max())
        g = blend_gripper(0.0 if src == OPERATOR else 0.04, g_off, w)
        # per tick the gripper moves by at most its offset's share of one tick of the blend (all of it, once)
        assert abs(g - g_cmd) <= abs(g_off) * (min(1.0, DT / blend) if blend > 0 else 1.0) + 1e-12 or w == 1.0
        q_prev, g_cmd = q, g
    # a blend weight is 0 at the switch and 1 after blend_s
    assert blend_weight(0.0, 0.2) == 0.0 and blend_weight(0.2, 0.2) == 1.0 and blend_weight(0.0, 0.0) == 1.0


def test_at_the_switch_the_target_does_not_move():
    q_prev = np.array([0.3, -0.2])
    leader = np.array([0.5, 0.1])  # 0.2 / 0.3 rad away: the offset carries the whole gap at w = 0
    q = handover_target(leader, q_prev - leader, 0.0, q_prev, V_MAX, DT)
    assert np.allclose(q, q_prev, rtol=0, atol=1e-15)  # rounding only


def test_bad_config_is_one_line():
    from hardware.errors import ConfigError

    with pytest.raises(ConfigError, match="release_nm below grab_nm"):
        TakeoverConfig(grab_nm=0.1, release_nm=0.2).validate()


def test_gripper_keeps_the_policys_squeeze_until_the_trigger_picks_it_up():
    """A takeover while the policy squeezes a held object: the resting trigger (at the object's width) must
    not open the gripper; squeezing picks the command up, and so does working the trigger open."""
    from factr2_teleop.teleop.takeover import GRIP_MOVE_M, gripper_pickup

    held, pick = 0.0002, None  # m: the policy's command, past the 9.6 mm object's width
    rng = np.random.default_rng(0)
    for _ in range(500):  # the hand rests: the trigger's target jitters at the object's width
        g, picked, pick = gripper_pickup(held, 0.0099 + rng.normal(0.0, 1e-4), pick)
        assert not picked and g == held
    g, picked, pick = gripper_pickup(held, 0.0, pick)  # the hand squeezes past the command: picked up
    assert picked and g == 0.0
    # from the other side: the hand opens the trigger (to let go) -- picked once it moved GRIP_MOVE_M
    pick, g_t = None, 0.0099
    for _ in range(100):
        g, picked, pick = gripper_pickup(held, g_t, pick)
        if picked:
            break
        assert g == held
        g_t += 0.0001
    assert picked and g_t >= 0.0099 + GRIP_MOVE_M - 1e-9
    assert gripper_pickup(held, float("nan"), None)[:2] == (held, False)  # no reading: keep the command
