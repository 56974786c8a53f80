"""LoopTiming's whole-run summary (factr2_teleop/teleop/timing.py): every tick since the start, not the ring's
last `capacity` ticks, with flat memory (histograms folded in as the ring wraps)."""

from __future__ import annotations

import numpy as np
import pytest

from factr2_teleop.teleop.timing import LoopTiming


def _run(periods_s, cpu_s, capacity=64):
    tm = LoopTiming(500.0, capacity=capacity)
    t = 0.0
    for k, (p, c) in enumerate(zip(periods_s, cpu_s, strict=True)):
        if k:
            t += p
        tm.record(t, 0.5 * c, c, 0.1 * c)
    return tm


@pytest.mark.parametrize("n", [1, 2, 63, 64, 65, 128, 129, 1000])
def test_whole_run_matches_the_exact_statistics_of_every_tick(n):
    rng = np.random.default_rng(n)
    periods = np.where(rng.random(n) < 0.1, rng.uniform(0.003, 0.05, n), rng.normal(0.002, 5e-5, n))
    periods[0] = 0.0  # the first tick starts the clock: no period
    cpu = rng.uniform(0.0002, 0.0009, n)
    st = _run(periods, cpu).stats(whole_run=True)
    p = periods[1:]
    assert st.ticks == n
    if n > 1:
        assert st.rate_hz == pytest.approx(1.0 / p.mean(), rel=1e-9)
        assert st.period_max_ms == pytest.approx(p.max() * 1e3)
        for q, got in ((0.99, st.period_p99_ms), (0.5, st.period_p50_ms)):
            v = np.sort(p)[int(np.ceil(q * p.size)) - 1]  # the value at the quantile's rank
            width = 10e-6 if v < 0.020 else 1e-3  # a quantile is the upper edge of its value's bin
            assert v * 1e3 - 1e-6 <= got <= (v + width) * 1e3 + 1e-6
    assert st.cpu_mean_ms == pytest.approx(cpu.mean() * 1e3, rel=1e-9)
    assert st.cpu_share == pytest.approx(cpu.mean() * 500.0, rel=1e-9)
    assert st.sim_cpu_mean_ms == pytest.approx(0.1 * cpu.mean() * 1e3, rel=1e-9)


def test_a_slow_start_is_in_the_whole_run_and_not_in_the_window():
    n = 1000
    periods = np.full(n, 0.002)
    periods[1:200] = 0.004  # the first 200 ticks at half rate: the window of the last 64 never sees them
    tm = _run(periods, np.full(n, 0.0004))
    window, whole = tm.stats(), tm.stats(whole_run=True)
    assert window.rate_hz == pytest.approx(500.0)
    assert whole.rate_hz == pytest.approx(1.0 / periods[1:].mean())
    assert whole.rate_hz < 420.0
    assert whole.period_p99_ms == pytest.approx(4.0, abs=0.011)
    assert window.period_p99_ms == pytest.approx(2.0)


def test_memory_does_not_grow_with_the_run():
    tm = _run(np.full(5000, 0.002), np.full(5000, 0.0004), capacity=16)
    sizes = (tm._all_periods.counts.size, tm._periods.size)
    for _ in range(3):
        t = tm._t_last
        for _ in range(5000):
            t += 0.002
            tm.record(t, 0.0002, 0.0004)
    assert (tm._all_periods.counts.size, tm._periods.size) == sizes
    assert tm.stats(whole_run=True).ticks == 20000
    assert tm._all_periods.n + 16 >= 19999


def test_an_empty_run_says_nan_not_a_number_it_does_not_have():
    st = LoopTiming(500.0).stats(whole_run=True)
    assert st.ticks == 0 and np.isnan(st.rate_hz) and np.isnan(st.period_p99_ms)
