"""A Bus Watchdog(98) that latched on the servo's side only: the app's own sends show no gap (a slow start
between connect and the loop's first tick, seen by the servo's clock, not by the app's), yet the servo
stopped and refuses every goal current. The leader must see it from what the servo says (the register
reads -1), re-arm it (0, then the period), say so once, and have its goal currents obeyed again.

Deterministic: one LockstepClock for the app; the emulated servos' clock is the same plus a skew the test
advances, so the servos see a silence the app's clock does not (no reliance on a slow machine)."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.sim.motors import IdealMotorBank


@pytest.fixture
def skewed():
    """(clock, skew, bank, emu, leader) not yet connected; disconnected and closed after the test."""
    from hardware.clock import LockstepClock
    from hardware.dynamixel.config import DynamixelLeaderConfig
    from hardware.dynamixel.leader import DynamixelLeader
    from hardware.types import JointLimits

    clock, skew = LockstepClock(5.0), [0.0]  # skew [s]: the servos' clock minus the app's
    bank = IdealMotorBank(2, torque_constant=0.35, q0=np.array([0.1, -0.2]))
    emu = DynamixelEmulator(bank, [1, 2], "XL330-M288", emulate_return_delay=False, transport="inprocess",
                            clock=lambda: clock.now() + skew[0])
    lim = JointLimits(q_min=np.full(2, -5.0), q_max=np.full(2, 5.0), v_max=np.full(2, 10.0),
                      tau_max=np.full(2, 0.3), tau_rate_max=np.full(2, 1e4))
    cfg = DynamixelLeaderConfig(port=emu.port_path, ids=[1, 2], signs=[1, 1], offsets_rad=[0.0, 0.0],
                                gripper_id=None, model="XL330-M288", loop_hz=10.0, rx_timeout_ms=30.0)
    leader = DynamixelLeader(cfg, lim, clock=clock)
    yield clock, skew, bank, emu, leader
    leader.disconnect()
    emu.close()


def tick(clock, leader, tau=(0.2, -0.2)):
    clock._t += 0.002
    leader.read()
    leader.command_torque(np.array(tau))


def latched_lines(leader):
    return [w for w in leader.warnings if "Bus Watchdog had latched" in w]


@pytest.mark.parametrize("check", [True, False])
def test_a_servo_side_gap_before_the_first_tick_is_seen_and_re_armed(check, skewed, monkeypatch):
    clock, skew, bank, emu, leader = skewed
    if not check:  # the keeper as it was: it infers a trip only from gaps in the app's own sends
        monkeypatch.setattr(wd.BusWatchdogKeeper, "check", lambda self, bus, now, ids=None: [])
    leader.connect()
    assert all(s.table[98] == 5 for s in emu.servos)
    skew[0] += 0.3  # the servos hear nothing for 0.3 s; the app's clock moved 0 s (its sends: no gap)
    for _ in range(5):
        tick(clock, leader)
    assert [i for i, _, _ in emu.watchdog_trips] == [1, 2]  # the gap was real: both latched
    if not check:  # the bug: every goal current refused, no word of it
        assert all(s.watchdog.latched for s in emu.servos) and np.all(bank.current_cmd == 0)
        assert latched_lines(leader) == []
        return
    assert not any(s.watchdog.latched for s in emu.servos) and all(s.table[98] == 5 for s in emu.servos)
    assert np.all(bank.current_cmd != 0)  # obeyed again from the first tick
    said = latched_lines(leader)
    assert len(said) == 1 and "ids [1, 2]" in said[0] and "re-armed" in said[0]


def test_a_latch_during_the_run_is_found_by_the_periodic_read_back_and_said_once(skewed):
    clock, skew, bank, emu, leader = skewed
    leader.connect()
    tick(clock, leader)
    assert np.all(bank.current_cmd != 0) and latched_lines(leader) == []
    for _ in range(2):  # twice: the second time is logged, not warned again
        skew[0] += 0.3
        tick(clock, leader)
        assert all(s.watchdog.latched for s in emu.servos) and np.all(bank.current_cmd == 0)
        for _ in range(int(wd.CHECK_EVERY_S / 0.002) + 1):  # all read back every CHECK_EVERY_S
            tick(clock, leader)
        assert not any(s.watchdog.latched for s in emu.servos) and np.all(bank.current_cmd != 0)
    assert len(latched_lines(leader)) == 1 and leader._wd.found == 4


def test_check_reads_the_register_and_re_arms_only_what_latched(skewed):
    clock, skew, bank, emu, leader = skewed
    leader.connect()
    k = leader._wd
    assert k.check(leader.bus, clock.now()) == []  # both read back 5: nothing written
    s = emu.servo(2)
    s.table[98], s.watchdog.latched = 0xFF, True
    assert write_goal(leader, 2, 50) == p.ERR_DATA_RANGE  # a latched servo refuses a goal, said
    assert k.check(leader.bus, clock.now()) == [2]
    assert not s.watchdog.latched and s.table[98] == 5 and write_goal(leader, 2, 50) == p.ERR_NONE


def write_goal(leader, dxl_id, units):
    from hardware.errors import DeviceError

    try:
        leader.bus.write(dxl_id, p.ADDR_GOAL_CURRENT, units)
    except DeviceError as e:
        return p.ERR_DATA_RANGE if "range" in str(e).lower() else -1
    return p.ERR_NONE


def test_close_gives_a_servo_latched_since_the_last_read_back_0_a(skewed):
    clock, skew, bank, emu, leader = skewed
    leader.connect()
    tick(clock, leader)
    skew[0] += 0.3
    tick(clock, leader)  # latched; the next read-back is CHECK_EVERY_S away
    assert all(s.watchdog.latched and s.get(p.ADDR_GOAL_CURRENT, signed=True) != 0 for s in emu.servos)
    leader.zero_torque("stop")  # the stop's 0 A: refused by a latched servo (a sync write says nothing)
    assert all(s.get(p.ADDR_GOAL_CURRENT, signed=True) != 0 for s in emu.servos)
    leader.disconnect()
    for s in emu.servos:
        assert s.get(p.ADDR_TORQUE_ENABLE) == 0 and s.get(p.ADDR_GOAL_CURRENT, signed=True) == 0
        assert not s.watchdog.latched
