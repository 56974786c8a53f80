"""Degrade, don't fail (issue #53): a real-time loop that cannot hold its rate on this machine runs at a lower
rate it can hold, says so once, and scales the force-feedback gains for it.

Why scale the gains: a sampled force-feedback loop renders a stiffness that is stable only below ~2 b / T
(Colgate and Schenkel, passivity of sampled haptic displays: T the period, b the device's damping), so a
loop at half the rate keeps the same margin with half the feedback gain. What a slower loop does to
everything else is rate-independent already: the feedback ramps are in seconds, the safety layer's rate
limits use the real time between commands, the observer integrates the measured dt.

The judgement is one pure function on a window of ticks (`judge_window`); `RateGovernor` is its shell.
"""

from __future__ import annotations

from dataclasses import dataclass

WINDOW_S = 2.0  # s: ticks judged at once (the first window after the start is warm-up: not judged)
HELD_FRACTION = 0.95  # a window that ran fewer than this share of its due ticks did not hold the rate
BUSY_FRACTION = 0.8  # ... nor one whose median tick took more than this share of the period (no margin)
MIN_RATE_HZ = 100.0  # Hz: never below this (a 10 ms loop still holds the pair within its stale windows)
STEP = 0.5  # each degradation halves the rate (500 -> 250 -> 125 Hz)
BAD_WINDOWS = 2  # windows in a row that did not hold the rate before it drops: a 2 s burst of another
# process's load is not a machine that cannot hold the rate (the rate does not come back up)


@dataclass(frozen=True)
class Verdict:
    """new_rate_hz: the rate to run at now (None: keep the rate); held: share of the due ticks run;
    busy_ms: median time inside a tick [ms]; line: what to say (once), "" when nothing changes."""

    new_rate_hz: float | None
    held: float
    busy_ms: float
    line: str = ""


def judge_window(rate_hz: float, ticks: int, wall_s: float, busy_median_s: float) -> Verdict:
    """Whether a window of `ticks` ticks over `wall_s` [s] of wall time, with a median time inside a tick of
    `busy_median_s` [s], held `rate_hz` [Hz]; if not, the lower rate to run at (None when already at
    MIN_RATE_HZ)."""
    held = ticks / (wall_s * rate_hz) if wall_s > 0 and rate_hz > 0 else 1.0
    period = 1.0 / rate_hz
    busy_ms = busy_median_s * 1e3
    if held >= HELD_FRACTION and busy_median_s <= BUSY_FRACTION * period:
        return Verdict(None, held, busy_ms)
    new = rate_hz * STEP
    if new < MIN_RATE_HZ:
        return Verdict(None, held, busy_ms)
    why = (f"ran {100 * held:.0f} % of its ticks" if held < HELD_FRACTION
           else f"a tick takes {busy_ms:.2f} ms of its {period * 1e3:.1f} ms")
    return Verdict(new, held, busy_ms,
                   f"this machine cannot hold {rate_hz:.0f} Hz ({why} over {WINDOW_S:.0f} s): running at "
                   f"{new:.0f} Hz, force-feedback gains x{STEP:g} for that rate")


class RateGovernor:
    """Feed it every tick (start time, time inside the tick); it returns a Verdict with a new rate when
    BAD_WINDOWS whole windows in a row could not hold the current one."""

    def __init__(self, rate_hz: float, window_s: float = WINDOW_S):
        self.rate_hz, self.window_s = float(rate_hz), float(window_s)
        self._t0: float | None = None
        self._busy: list[float] = []
        self._warm = False  # the first window is warm-up (first calls, caches): not judged
        self._bad = 0  # windows in a row that did not hold the rate

    def tick(self, t_start: float, busy_s: float) -> Verdict | None:
        if self._t0 is None:
            self._t0 = t_start
        self._busy.append(busy_s)
        wall = t_start - self._t0
        if wall < self.window_s:
            return None
        busy = sorted(self._busy)
        n = len(busy) - 1  # ticks whose period lies inside the window (the last one starts it)
        v = judge_window(self.rate_hz, n, wall, busy[len(busy) // 2])
        self._t0, self._busy = t_start, []
        if not self._warm:
            self._warm = True
            return None
        if v.new_rate_hz is None:
            self._bad = 0
            return v
        self._bad += 1
        if self._bad < BAD_WINDOWS:
            return Verdict(None, v.held, v.busy_ms)
        self.rate_hz, self._bad = v.new_rate_hz, 0
        self._warm = False  # the next window settles at the new rate
        return v
