"""Demo metrics (pure): feedback mapped back to the follower, correlation, lag, command violations."""

from __future__ import annotations

import numpy as np

from factr2_teleop.demo import metrics as M
from factr2_teleop.teleop.feedback import FeedbackConfig, FeedbackGate  # noqa: F401 -- law under test below
from factr2_teleop.teleop.mapping import JointMap, JointMapConfig


def test_feedback_on_follower_inverts_the_law_through_a_permuted_signed_map():
    mp = JointMap(JointMapConfig(index=[1, 0, 2], sign=[1, -1, 1], scale=[1, 1, 2]), 3, 3)
    gain = np.array([0.1, 0.2, 0.05])
    tau_ext = np.array([[1.0, -2.0, 3.0], [0.5, 0.0, -1.0]])
    fb = np.array([-gain * mp.torque_back(t) for t in tau_ext])  # the law: tau_fb = -K_f M^T(tau_ext)
    back = M.feedback_on_follower(fb, gain, mp.index, mp.k)
    assert np.allclose(back, tau_ext)


def test_zero_gain_joint_is_nan_not_zero():
    back = M.feedback_on_follower(np.ones((2, 2)), np.array([0.0, 1.0]), np.array([0, 1]), np.ones(2))
    assert np.all(np.isnan(back[:, 0])) and np.allclose(back[:, 1], -1.0)


def test_corr_per_joint_and_constant_joint_is_nan():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 3))
    y = x.copy()
    y[:, 1] = -x[:, 1]
    y[:, 2] = 0.0
    c = M.per_joint_corr(x, y, np.ones(500, bool))
    assert c[0] > 0.999 and c[1] < -0.999 and np.isnan(c[2])


def test_lag_found_by_cross_correlation():
    dt = 0.002
    t = np.arange(3000) * dt
    true = np.stack([np.sin(2 * np.pi * 0.7 * t), np.sign(np.sin(2 * np.pi * 0.3 * t))], axis=1)
    k = 7  # 14 ms
    est = np.vstack([np.zeros((k, 2)), true[:-k]])
    assert abs(M.lag_by_xcorr(est, true, dt) - k * dt) < 1e-9
    assert M.lag_by_xcorr(true, true, dt) == 0.0


def test_lag_uses_changes_despite_slow_bias_and_noise():
    """Contact on/off with a pressing force that varies, the estimate delayed 6 ms, plus a slow pose-like
    bias and sensor noise: the delay of the changes is found."""
    dt = 0.001
    t = np.arange(20000) * dt
    rng = np.random.default_rng(1)
    on = (np.sin(2 * np.pi * 0.25 * t) > 0.3).astype(float)
    true = np.stack([on * (2 + np.sin(2 * np.pi * 0.4 * t)), on * (1 + 0.5 * np.cos(2 * np.pi * 0.3 * t))], 1)
    k = 6
    bias = np.stack([0.4 * np.sin(2 * np.pi * 0.05 * t + 1), 0.3 * np.sin(2 * np.pi * 0.07 * t)], 1)
    est = np.vstack([np.zeros((k, 2)), true[:-k]]) + bias + 0.01 * rng.standard_normal(true.shape)
    assert abs(M.lag_by_xcorr(est, true, dt) - k * dt) < 1.5e-3


def test_command_violations_counts_range_and_speed_but_not_holds():
    q_min, q_max, v_max = np.array([-1.0, -1.0]), np.array([1.0, 1.0]), np.array([1.0, 1.0])
    t = np.arange(5) * 0.01
    q = np.array([[0, 0], [0.005, 0], [0.01, 1.2], [0.01, 0.9], [0.5, 0.9]], float)
    # (2, j1) out of range; steps (1->2, j1) 1.2 and (2->3, j1) 0.3 > 1*(0.01+0.002); (3->4, j0) 0.49
    assert M.command_violations(q, t, q_min, q_max, v_max, 0.002) == 4
    hold = np.array([False, False, False, False, True])
    assert M.command_violations(q, t, q_min, q_max, v_max, 0.002, hold=hold) == 3
    assert M.command_violations(np.array([[np.nan, 0.0]]), t[:1], q_min, q_max, v_max, 0.002) == 1


def test_command_violations_bracket_issue_and_send_times():
    """A thread preempted between issuing a command and the safety layer's clock read: by issue times the
    step looks too fast (0.012 rad in 2 ms at 1 rad/s), but it went on the wire 14 ms after the previous
    command was issued, which the layer's budget may use. A step too fast even for that bracket counts."""
    lim = (np.array([-1.0]), np.array([1.0]), np.array([1.0]))
    t = np.array([0.0, 0.002])
    q = np.array([[0.0], [0.012]])
    assert M.command_violations(q, t, *lim, 0.0) == 1  # issue times only, no slack
    assert M.command_violations(q, t, *lim, 0.0, t_sent=np.array([0.0001, 0.014])) == 0
    assert M.command_violations(q, t, *lim, 0.0, t_sent=np.array([0.0001, 0.010])) == 1


def test_torque_violations_and_l1():
    assert M.torque_violations(np.array([[0.5, -0.9], [0.91, np.nan]]), np.array([0.9, 0.9])) == 2
    tau = np.array([[1.0, -1.0], [2.0, 0.0], [np.nan, 0.0]])
    assert M.l1_mean(tau, np.array([True, True, True])) == 2.0
    assert np.isnan(M.l1_mean(tau, np.zeros(3, bool)))


def test_resample_makes_jittery_ticks_uniform_for_the_lag():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.0015, 0.004, size=4000))
    true = np.stack([np.sin(2 * np.pi * 0.8 * t), np.cos(2 * np.pi * 0.5 * t)], axis=1)
    est = np.stack([np.sin(2 * np.pi * 0.8 * (t - 0.012)), np.cos(2 * np.pi * 0.5 * (t - 0.012))], axis=1)
    lag = M.lag_by_xcorr(M.resample(t, est, 0.001), M.resample(t, true, 0.001), 0.001)
    assert abs(lag - 0.012) <= 0.0015
