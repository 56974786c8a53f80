"""The Dynamixel emulator's Bus Watchdog(98): the e-Manual's semantics (hardware/dynamixel/watchdog.py) for
every emulated servo -- armed by a write with torque on, fed by every instruction packet, tripped when the
host is silent for its period (goal refused until cleared).

SIMULATED DEVICE. A mixin of DynamixelEmulator (emulator.py); the attributes are the emulator's.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.servo_table import ServoTable


class EmulatorWatchdog:
    """Bus Watchdog(98) of the emulated servos (mixed into DynamixelEmulator)."""

    # -- Bus Watchdog(98) ------------------------------------------------------------------------------
    def poll_watchdogs(self) -> None:
        """Latch every servo whose watchdog expired by now (the pty thread calls this at each deadline; a
        twin stepping an in-process emulator calls it every step; from any other thread a pty emulator's
        call does nothing: its own thread keeps the deadlines)."""
        if not self._wd_armed or (self._thread is not None and threading.get_ident() != self._thread.ident):
            return
        now = self._tick_clock()
        if now > self._wd_due:
            self._watchdog_expire(now)

    def _watchdog_expire(self, now: float) -> None:
        for s in self.servos:  # (the serving thread, or the in-process caller's: never both)
            if s.watchdog.expire(now, s.table[wd.ADDR[0]], s.torque_on):
                self._watchdog_trip(s)
        self._wd_due = self._watchdog_deadline()

    def _watchdog_deadline(self) -> float:
        return min((s.watchdog.deadline(s.table[wd.ADDR[0]], s.torque_on) for s in self.servos),
                   default=math.inf)

    def _watchdog_rx(self) -> None:
        """An instruction packet reached the servos: expire what ran out before it, then restart the timers
        of the servos that heard it (a silent servo, cable out, hears nothing)."""
        now = self._tick_clock()
        if now > self._wd_due:
            self._watchdog_expire(now)
        if self.silent:
            return
        silent = self.silent_ids
        for s in self.servos:
            if s.id not in silent:
                s.watchdog.last_rx_s = now
        self._wd_due = self._watchdog_deadline() if silent else now + self._wd_min_period

    def _watchdog_trip(self, s: ServoTable) -> None:
        """The servo stops: Bus Watchdog(98) reads -1; current mode outputs 0 A, position modes hold the
        present position, other modes no torque. Torque Enable and Hardware Error Status are untouched."""
        s.table[wd.ADDR[0]] = wd.ERROR_VALUE & 0xFF
        self.watchdog_trips.append((s.id, float(s.watchdog.t_tripped), float(self._tick_clock())))
        idx = np.array([s.index])
        mode = s.table[p.ADDR_OPERATING_MODE[0]]
        holds = mode in (p.OP_MODE_POSITION, p.OP_MODE_EXTENDED_POSITION, p.OP_MODE_CURRENT_BASED_POSITION)
        if holds:
            self._refresh([s])  # where it is now, not at the last read
        with self._bank_lock:
            if holds:
                q = s.joint_angle(s.get(p.ADDR_PRESENT_POSITION, signed=True))
                self.bank.command_position(idx, np.array([q]))
            else:
                self.bank.command_current(idx, np.zeros(1))
        self._watchdog_rearm_state()

    def _watchdog_written(self, s: ServoTable) -> None:
        """Bus Watchdog(98) or Torque Enable(64) written: 0 clears a latched error; the timer starts now."""
        if s.table[wd.ADDR[0]] == 0:
            s.watchdog.latched = False
        s.watchdog.last_rx_s = self._tick_clock()
        self._watchdog_rearm_state()

    def _watchdog_rearm_state(self) -> None:
        a = wd.ADDR[0]
        periods = [s.table[a] * wd.UNIT_S for s in self.servos
                   if 0 < s.table[a] <= wd.MAX_UNITS and s.torque_on and not s.watchdog.latched]
        self._wd_armed = bool(periods)
        self._wd_min_period = min(periods, default=math.inf)
        self._wd_due = self._watchdog_deadline()
