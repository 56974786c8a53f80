"""Measured loop timing as a pure ring-buffer statistics object (no clock of its own, no threads).

The loop calls record(t_start, compute_s, cpu_s) once per tick with the start time on the rig clock; the
period is the difference of consecutive starts. cpu_s is the CPU time the loop's own thread spent in the tick
(time.thread_time) less what an in-process twin emulator did on it (hardware/sim_cpu.py): the app's cost
alone, as with hardware, without the waits on the wire that compute_s includes. stats() summarises the last
`capacity` ticks (the live display: ~8 s at 500 Hz); stats(whole_run=True) every tick since the start (the
summary a session prints and a benchmark reports), from histograms folded in each time the ring wraps, so the
memory stays flat over a day of teleop. Before the whole-run summary existed, the end-of-run line of a 30 s
run described only its last 8 s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OVERRUN_FACTOR = 1.5  # a period longer than this times the target period counts as an overrun
# whole-run histograms' bin edges [s]: 10 us up to 20 ms (periods and tick costs near a 500 Hz target), 1 ms
# up to 2 s; longer values land in the last bin (the maximum is kept exactly). A quantile: its bin's top.
_EDGES_S = np.concatenate([np.arange(0.0, 0.020, 10e-6), np.arange(0.020, 2.0 + 1e-9, 1e-3), [np.inf]])


def _hist_quantile(counts: np.ndarray, q: float, vmax: float) -> float:
    """The q-quantile (0..1) of values histogrammed on _EDGES_S: the upper edge of the bin that holds it,
    never above the exact maximum vmax."""
    n = counts.sum()
    if n == 0:
        return float("nan")
    k = int(np.searchsorted(np.cumsum(counts), q * n, side="left"))
    return float(min(_EDGES_S[min(k + 1, len(_EDGES_S) - 1)], vmax))


class _WholeRun:
    """Histogram, count, sum and max of one series over a whole run (blocks of the ring folded in)."""

    def __init__(self):
        self.counts = np.zeros(len(_EDGES_S) - 1, np.int64)
        self.n, self.total, self.vmax = 0, 0.0, float("-inf")

    def fold(self, x: np.ndarray) -> None:
        x = x[np.isfinite(x)]
        if x.size:
            self.counts += np.histogram(np.clip(x, 0.0, None), _EDGES_S)[0]
            self.n += x.size
            self.total += float(x.sum())
            self.vmax = max(self.vmax, float(x.max()))

    def merged(self, x: np.ndarray) -> _WholeRun:
        """A copy with the ring's not-yet-folded values x added."""
        out = _WholeRun()
        out.counts, out.n, out.total, out.vmax = self.counts.copy(), self.n, self.total, self.vmax
        out.fold(x)
        return out

    def mean(self) -> float:
        return self.total / self.n if self.n else float("nan")

    def quantile(self, q: float) -> float:
        return _hist_quantile(self.counts, q, self.vmax)


@dataclass(frozen=True)
class TimingStats:
    """rate_hz: 1 / mean period over the window; period_p50_ms / p99 / max [ms]; compute_p99_ms: time spent
    inside the tick [ms]; cpu_mean_ms / cpu_p99_ms: CPU of the loop's thread per tick [ms] and cpu_share: its
    mean over the target period (the margin a slower machine eats; target <= 0.25), the loop's own: without
    sim_cpu_mean_ms, the CPU a twin did on the loop's thread (in-process emulator, simulated hand, ground
    truth: hardware/sim_cpu.py; 0 with hardware); overruns: cumulative periods > OVERRUN_FACTOR x target;
    ticks: cumulative."""

    target_hz: float
    rate_hz: float
    period_p50_ms: float
    period_p99_ms: float
    period_max_ms: float
    compute_p99_ms: float
    overruns: int
    ticks: int
    cpu_mean_ms: float = float("nan")
    cpu_p99_ms: float = float("nan")
    cpu_share: float = float("nan")
    sim_cpu_mean_ms: float = 0.0

    def line(self) -> str:
        twin = f" + twin {self.sim_cpu_mean_ms:.2f} ms on its thread" if self.sim_cpu_mean_ms > 0 else ""
        cpu = (f", loop CPU {self.cpu_mean_ms:.2f} ms/tick ({100 * self.cpu_share:.0f} % of the period){twin}"
               if self.cpu_mean_ms == self.cpu_mean_ms else "")
        return (f"{self.rate_hz:6.1f} Hz (target {self.target_hz:.0f}), "
                f"period p50 {self.period_p50_ms:.2f} ms "
                f"p99 {self.period_p99_ms:.2f} ms max {self.period_max_ms:.2f} ms, compute p99 "
                f"{self.compute_p99_ms:.2f} ms{cpu}, {self.overruns} overruns / {self.ticks} ticks")


class LoopTiming:
    def __init__(self, target_hz: float, capacity: int = 4096, overrun_factor: float = OVERRUN_FACTOR):
        if not target_hz > 0 or capacity < 2:
            raise ValueError("LoopTiming needs target_hz > 0 and capacity >= 2")
        self.target_hz, self.capacity, self.overrun_factor = float(target_hz), int(capacity), overrun_factor
        self._periods = np.zeros(capacity)
        self._compute = np.zeros(capacity)
        self._cpu = np.full(capacity, np.nan)
        self._sim = np.zeros(capacity)
        self._n_periods = 0  # cumulative
        self._n_compute = 0
        self.ticks = 0
        self.overruns = 0
        self._t_last = float("nan")
        # whole run: each ring block is folded in when the ring wraps onto it (record), the rest at stats()
        self._all_periods, self._all_compute, self._all_cpu, self._all_sim = (_WholeRun(), _WholeRun(),
                                                                              _WholeRun(), _WholeRun())

    def record(self, t_start: float, compute_s: float, cpu_s: float = float("nan"),
               sim_s: float = 0.0) -> None:
        """One tick that started at t_start [s] and spent compute_s [s] in the loop body, cpu_s [s] of it
        on the loop thread's CPU for the app (NaN: not measured) and sim_s [s] for a twin (sim_cpu)."""
        self.ticks += 1
        if self._n_compute and self._n_compute % self.capacity == 0:  # the ring wraps: keep what it held
            self._all_compute.fold(self._compute)
            self._all_cpu.fold(self._cpu)
            self._all_sim.fold(self._sim)
        self._compute[self._n_compute % self.capacity] = compute_s
        self._cpu[self._n_compute % self.capacity] = cpu_s
        self._sim[self._n_compute % self.capacity] = sim_s
        self._n_compute += 1
        if np.isfinite(self._t_last):
            period = t_start - self._t_last
            if self._n_periods and self._n_periods % self.capacity == 0:
                self._all_periods.fold(self._periods)
            self._periods[self._n_periods % self.capacity] = period
            self._n_periods += 1
            if period > self.overrun_factor / self.target_hz:
                self.overruns += 1
        self._t_last = t_start

    def reset_phase(self) -> None:
        """Forget the last start (after a deliberate pause) so the gap is not counted as a period."""
        self._t_last = float("nan")

    def stats(self, whole_run: bool = False) -> TimingStats:
        """The last `capacity` ticks, or (whole_run) every tick since the start."""
        if whole_run:
            return self._whole_run_stats()
        p = self._periods[: min(self._n_periods, self.capacity)]
        c = self._compute[: min(self._n_compute, self.capacity)]
        if p.size == 0:
            nan = float("nan")
            return TimingStats(self.target_hz, nan, nan, nan, nan,
                               float(np.percentile(c, 99) * 1e3) if c.size else nan, self.overruns,
                               self.ticks)
        mean = float(np.mean(p))
        cpu = self._cpu[: min(self._n_compute, self.capacity)]
        cpu = cpu[np.isfinite(cpu)]
        cpu_mean = float(np.mean(cpu)) if cpu.size else float("nan")
        sim_mean = float(np.mean(self._sim[: min(self._n_compute, self.capacity)]))
        return TimingStats(
            target_hz=self.target_hz, rate_hz=1.0 / mean if mean > 0 else float("inf"),
            period_p50_ms=float(np.percentile(p, 50) * 1e3), period_p99_ms=float(np.percentile(p, 99) * 1e3),
            period_max_ms=float(np.max(p) * 1e3), compute_p99_ms=float(np.percentile(c, 99) * 1e3),
            overruns=self.overruns, ticks=self.ticks, cpu_mean_ms=cpu_mean * 1e3,
            cpu_p99_ms=float(np.percentile(cpu, 99) * 1e3) if cpu.size else float("nan"),
            cpu_share=cpu_mean * self.target_hz, sim_cpu_mean_ms=sim_mean * 1e3)

    def _whole_run_stats(self) -> TimingStats:
        def rest(ring: np.ndarray, n: int) -> np.ndarray:  # the ring's values not folded in yet
            k = n % self.capacity if n else 0
            return ring[:k] if (k or n == 0) else ring  # a full ring just wrapped: all of it
        p = self._all_periods.merged(rest(self._periods, self._n_periods))
        c = self._all_compute.merged(rest(self._compute, self._n_compute))
        cpu = self._all_cpu.merged(rest(self._cpu, self._n_compute))
        sim = self._all_sim.merged(rest(self._sim, self._n_compute))
        nan = float("nan")
        mean = p.mean()
        cpu_mean = cpu.mean()
        return TimingStats(
            target_hz=self.target_hz, rate_hz=1.0 / mean if mean > 0 else (nan if p.n == 0 else float("inf")),
            period_p50_ms=p.quantile(0.5) * 1e3, period_p99_ms=p.quantile(0.99) * 1e3,
            period_max_ms=p.vmax * 1e3 if p.n else nan, compute_p99_ms=c.quantile(0.99) * 1e3,
            overruns=self.overruns, ticks=self.ticks, cpu_mean_ms=cpu_mean * 1e3,
            cpu_p99_ms=cpu.quantile(0.99) * 1e3, cpu_share=cpu_mean * self.target_hz,
            sim_cpu_mean_ms=(sim.mean() if sim.n else 0.0) * 1e3)
