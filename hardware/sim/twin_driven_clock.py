"""TwinDrivenClock: real time, with the caller's thread stepping a twin (hardware/sim/twin.py) after each
sleep (SIMULATED).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hardware.clock import Clock

if TYPE_CHECKING:
    from hardware.sim.twin import Twin

# s: a twin driven by the caller's thread (TwinDrivenClock) further behind wall time than this skips ahead
# (a stall: swap, suspend) rather than spiral (counted in .overruns)
DRIVEN_MAX_LAG_S = 0.05


class TwinDrivenClock(Clock):
    """Real time, but the caller's thread steps the twin: after each sleep the physics catches up to wall
    time (Twin.catch_up), so physics, emulators and the loop run in ONE thread in a fixed order, with no
    GIL hand-offs between a stepping thread and the loop (the jitter source of an in-process real-time
    twin). Same time base as hardware.clock.Clock (the drivers' clock). The twin's own thread must not run.

        clock = TwinDrivenClock(twin)   # twin.stop_realtime() first if it was started
        clock.start()                   # set-up time is not simulated; one step so fresh samples exist
        loop.run(clock)                 # each clock.sleep() steps the twin to now
    """

    def __init__(self, twin: Twin, max_lag_s: float = DRIVEN_MAX_LAG_S):
        self.twin, self.max_lag_s = twin, float(max_lag_s)

    @property
    def overruns(self) -> int:
        """Times the twin skipped ahead (the thread stalled for more than max_lag_s)."""
        return self.twin.overruns

    def start(self) -> None:
        """Sim time continues from now (set-up time is not simulated: the leader would fall meanwhile),
        then one step so that fresh samples exist, rebased again so the loop starts level with the twin."""
        if self.twin._rt_thread is not None:
            raise RuntimeError("TwinDrivenClock: the twin's own thread runs (call twin.stop_realtime())")
        self.twin.rebase(self.now())
        self.twin.advance(self.now() + self.twin.dt)
        self.twin.rebase(self.now())

    def sleep(self, dt_s: float) -> None:
        super().sleep(dt_s)
        self.twin.catch_up(self.now(), self.max_lag_s)

    def sleep_until(self, t: float) -> None:
        super().sleep_until(t)
        self.twin.catch_up(self.now(), self.max_lag_s)
