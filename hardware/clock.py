"""Clocks: real time for hardware and interactive twins, lockstep for deterministic simulation.

Everything that waits (loops, drivers' timeouts, watchdogs) asks a Clock, so the same code runs against a
real arm, a real-time twin, or a lockstep twin that advances only when the loop sleeps.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class Clock:
    """now() [s] and sleep(dt_s)."""

    realtime = True

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, dt_s: float) -> None:
        if dt_s > 0:
            time.sleep(dt_s)

    def sleep_until(self, t: float) -> None:
        self.sleep(t - self.now())


class LockstepClock(Clock):
    """Simulated time: sleep(dt) advances the attached stepper (a twin) by dt, as fast as the CPU allows."""

    realtime = False

    def __init__(self, t0: float = 0.0):
        self._t = float(t0)
        self._steppers: list[Callable[[float], None]] = []

    def attach(self, advance: Callable[[float], None]) -> None:
        """advance(t_target) must bring the simulation to t_target [s]."""
        self._steppers.append(advance)

    def now(self) -> float:
        return self._t

    def sleep(self, dt_s: float) -> None:
        if dt_s <= 0:
            return
        self._t += dt_s
        for advance in self._steppers:
            advance(self._t)
