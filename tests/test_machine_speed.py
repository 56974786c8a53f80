"""The tests' machine-speed factor (tests/machine_speed.py) and the slowed core's CPU bandwidth
(bench/slow_core.py), as pure functions (#53)."""

from __future__ import annotations

import pytest
from machine_speed import MAX_SLOWDOWN, factor_of, slowdown

from bench.slow_core import QUOTA_MIN_US, bandwidth


def test_factor_is_the_median_over_the_reference_never_below_one_nor_above_the_cap():
    assert factor_of([0.1, 0.3, 0.2], reference_s=0.1) == pytest.approx(2.0)  # median, not the mean or max
    assert factor_of([0.01, 0.02, 0.03], reference_s=0.1) == 1.0  # a faster machine keeps the budgets
    assert factor_of([50.0], reference_s=0.1) == MAX_SLOWDOWN


def test_this_session_has_a_factor(machine_slowdown):
    assert 1.0 <= machine_slowdown == slowdown() <= MAX_SLOWDOWN


@pytest.mark.parametrize("factor,period,cpus,want", [
    (2.8, 1000, 1, (2800, 1000)),  # 357 us asked: under the kernel's 1 ms minimum, so the period grows
    (2.8, 1000, 2, (1400, 1000)),  # was clamped to 1000 / 1000: a whole CPU, no slowdown of one thread
    (2.0, 1000, 4, (1000, 2000)),
    (2.8, 10000, 2, (10000, 7142)),
])
def test_slow_core_bandwidth_keeps_the_share_above_the_kernels_minimum_quota(factor, period, cpus, want):
    got = bandwidth(factor, period, cpus)
    assert got == want and got[1] >= QUOTA_MIN_US
    assert got[1] / got[0] == pytest.approx(cpus / factor, rel=1e-3)  # the share asked, whatever the period
