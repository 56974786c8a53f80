"""The pty emulator's thread waits on the wall clock for a Bus Watchdog deadline on the servos' clock (a
twin's sim time). A servo clock frozen at, or a hair before, the deadline (a paused twin; a twin's physics
thread starved by the emulator's own SCHED_FIFO 41 thread, above it) must not make that thread spin: it
wakes at most every WAKE_MIN_S of wall time, and the watchdog still expires only once the clock is past
its deadline, then at the next wake.

Deterministic: a fake servo clock the test sets by hand, and the waits the thread asks select() for while it
is frozen are recorded: none may be under WAKE_MIN_S (a spin asks for 0 s, whatever the machine's load). The
loop's iterations over a wall interval are bounded too (what WAKE_MIN_S allows, with room)."""

from __future__ import annotations

import os
import select
import time

import numpy as np
import pytest

from hardware.dynamixel import emulator as emulator_mod
from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.sim.motors import IdealMotorBank

WATCH_S = 0.3  # wall time over which the thread's iterations are counted [s]
UNITS = 5  # Bus Watchdog(98) = 5 x 20 ms


class FrozenClock:
    """The servos' clock [s]: moves only when the test sets it."""

    def __init__(self, t: float = 10.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


class RecordingSelect:
    """The emulator module's `select`, recording the timeout [s] of every select() its thread makes."""

    def __init__(self):
        self.waits: list[float] = []

    def __getattr__(self, name):  # poll, POLLIN, ...: the real module's
        return getattr(select, name)

    def select(self, r, w, x, timeout=None):
        self.waits.append(timeout)
        return select.select(r, w, x, timeout)


class CountingEmulator(DynamixelEmulator):
    """Counts the serving thread's loop iterations (one _service call each)."""

    iterations = 0

    def _service(self, ready: bool) -> None:
        self.iterations += 1
        super()._service(ready)


def txrx(fd: int, parser: p.PacketParser, dxl_id: int, field, value: int, timeout_s: float = 2.0):
    os.write(fd, p.build_instruction(dxl_id, p.INST_WRITE, p.le(field[0], 2) + p.le(value, field[1])))
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        r, _, _ = select.select([fd], [], [], 0.01)
        if r:
            got = parser.feed(os.read(fd, 4096))
            if got:
                return got[0]
    raise AssertionError("no status from the emulator")


@pytest.fixture
def armed(monkeypatch):
    """A pty emulator with servo 1 in current mode, torque on, Bus Watchdog 100 ms armed at clock t0."""
    rec = RecordingSelect()
    monkeypatch.setattr(emulator_mod, "select", rec)
    clock = FrozenClock()
    bank = IdealMotorBank(1, torque_constant=0.5, q0=np.array([0.3]))
    emu = CountingEmulator(bank, [1], "XL330-M288", emulate_return_delay=False,
                           operating_mode=p.OP_MODE_CURRENT, clock=clock)
    fd = os.open(emu.port_path, os.O_RDWR | os.O_NOCTTY)
    parser = p.PacketParser()
    try:
        assert txrx(fd, parser, 1, wd.ADDR, UNITS).error == 0
        assert txrx(fd, parser, 1, p.ADDR_TORQUE_ENABLE, 1).error == 0
        assert txrx(fd, parser, 1, p.ADDR_GOAL_CURRENT, 100).error == 0  # the last packet: the timer starts
        assert emu.drain(1.0)
        yield clock, emu, rec
    finally:
        os.close(fd)
        emu.close()


def iterations_over(emu: CountingEmulator, wall_s: float) -> int:
    n0 = emu.iterations
    time.sleep(wall_s)
    return emu.iterations - n0


@pytest.mark.parametrize("before_s", [0.0, 1e-6], ids=["at-the-deadline", "a-microsecond-before"])
def test_a_frozen_clock_at_the_deadline_does_not_spin_the_thread(armed, before_s):
    clock, emu, rec = armed
    due = clock.t + UNITS * wd.UNIT_S  # the servo's own formula (last instruction + period)
    clock.t = due - before_s  # frozen there: not past it, so nothing expires
    time.sleep(0.05)  # a wait asked before the clock was set ends within the idle 20 ms
    k = len(rec.waits)
    n = iterations_over(emu, WATCH_S)
    waits = rec.waits[k:]
    assert waits and min(waits) >= emulator_mod.WAKE_MIN_S, (
        f"the thread asked select() for {min(waits):.2e} s ({len(waits)} waits, {n} iterations in "
        f"{WATCH_S} s): it spins")
    assert n <= 1.5 * WATCH_S / emulator_mod.WAKE_MIN_S + 5
    assert emu.watchdog_trips == []  # the deadline itself is not "exceeded" (the e-Manual's rule)
    clock.t = due + 1e-6  # the clock moves past it: the next wake latches the servo
    deadline = time.monotonic() + 2.0
    while not emu.watchdog_trips and time.monotonic() < deadline:
        time.sleep(0.001)
    assert [i for i, *_ in emu.watchdog_trips] == [1]
    assert emu.watchdog_trips[0][1] == pytest.approx(due)  # latched at its deadline
    assert emu.bank.current_cmd[0] == 0.0  # current mode stops at 0 A


def test_an_idle_armed_thread_wakes_at_the_deadline_on_the_wall_clock():
    """The floor does not delay a wall-clock deadline beyond one WAKE_MIN_S: the servo still stops on time."""
    bank = IdealMotorBank(1, torque_constant=0.5, q0=np.array([0.3]))
    emu = DynamixelEmulator(bank, [1], "XL330-M288", emulate_return_delay=False,
                            operating_mode=p.OP_MODE_CURRENT)
    fd = os.open(emu.port_path, os.O_RDWR | os.O_NOCTTY)
    parser = p.PacketParser()
    try:
        assert txrx(fd, parser, 1, wd.ADDR, UNITS).error == 0
        assert txrx(fd, parser, 1, p.ADDR_TORQUE_ENABLE, 1).error == 0
        assert txrx(fd, parser, 1, p.ADDR_GOAL_CURRENT, 100).error == 0
        deadline = time.monotonic() + 2.0
        while not emu.watchdog_trips and time.monotonic() < deadline:
            time.sleep(0.001)
        assert [i for i, *_ in emu.watchdog_trips] == [1]
        _id, due, stopped = emu.watchdog_trips[0]
        assert stopped >= due  # never early; how late is the machine's scheduling, not checked here
    finally:
        os.close(fd)
        emu.close()
