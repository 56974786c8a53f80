"""How much slower the machine running the tests is than the one their time budgets were sized on (#53).

A test's deadline for something to happen (a renderer to open, teleop to leave soft start, a training run to
finish) is scaled by slowdown(); what the test asserts about behaviour is not. slowdown() times a fixed
CPU-bound reference workload (a teleop tick's kind of work: small numpy calls and plain Python over a 6-joint
vector) once per test session, the median of REPEATS runs, against REFERENCE_S, and never goes below 1 (a
faster machine keeps the budgets as written). FACTR2_TEST_SLOWDOWN=F sets the factor instead.

    from machine_speed import budget
    deadline = time.monotonic() + budget(20.0)   # 20 s on the dev VM, longer on a slower or busier machine
"""

from __future__ import annotations

import functools
import os
import statistics
import time

import numpy as np

# s: the workload's time on the 2-vCPU dev VM (`lscpu`: AMD EPYC): the fastest of 80 runs there, at load
# ~7 from other work, was 0.0425 s (median 0.07), so a quiet VM takes at most that; 0.040 rounds it down
REFERENCE_S = 0.040
REPEATS = 5
MAX_SLOWDOWN = 10.0  # a budget never grows more than this: a test that hangs still fails in bounded time


def reference_workload() -> float:
    """The fixed work timed: 2000 ticks of clip / abs / sum on 6 joints and a plain-Python sum of squares."""
    x, acc = np.zeros(6), 0.0
    for k in range(2000):
        x = np.clip(x + 0.001 * k, -1.0, 1.0)
        acc += float(np.abs(x).sum()) + sum(v * v for v in x.tolist())
    return acc


def factor_of(times_s: list[float], reference_s: float = REFERENCE_S) -> float:
    """The slowdown that workload times `times_s` [s] give: median / reference, within [1, MAX_SLOWDOWN]."""
    return min(MAX_SLOWDOWN, max(1.0, statistics.median(times_s) / reference_s))


@functools.cache
def slowdown() -> float:
    """This machine's slowdown against the dev VM (>= 1), measured on first use and kept for the session."""
    forced = os.environ.get("FACTR2_TEST_SLOWDOWN")
    if forced:
        return min(MAX_SLOWDOWN, max(1.0, float(forced)))
    times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        reference_workload()
        times.append(time.perf_counter() - t0)
    return factor_of(times)


def budget(seconds: float) -> float:
    """A time budget [s] sized on the dev VM, scaled to this machine."""
    return seconds * slowdown()
