"""Bus Watchdog(98) against the ROBOTIS e-Manual's description (hardware/dynamixel/watchdog.py cites it):
0 off / clears the error, 1..127 in 20 ms units, -1 the latched error; it monitors the interval between
instruction packets while torque is on; on expiry the servo stops and the Goal values become read-only
(Data Range Error) until 0 is written; from firmware v38 (every XL330)."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.sim.motors import MODE_CURRENT, MODE_POSITION, IdealMotorBank


class Clock:
    def __init__(self):
        self.t = 10.0

    def __call__(self):
        return self.t


def status(emu, dxl_id, inst, params=b""):
    got = p.parse_packets(emu.serve(p.build_instruction(dxl_id, inst, params)))
    return got[0] if got else None


def write(emu, dxl_id, field, value):
    return status(emu, dxl_id, p.INST_WRITE, p.le(field[0], 2) + p.le(value, field[1]))


def read(emu, dxl_id, field, signed=False):
    return p.from_le(status(emu, dxl_id, p.INST_READ, p.read_params(*field)).params, signed)


@pytest.fixture
def chain():
    clock = Clock()
    bank = IdealMotorBank(2, torque_constant=0.5, q0=np.array([0.4, -0.2]))
    emu = DynamixelEmulator(bank, [1, 2], ["XL330-M288", "XM430-W350"], emulate_return_delay=False,
                            operating_mode=p.OP_MODE_CURRENT, transport="inprocess", clock=clock,
                            firmware=[52, 52])
    yield clock, bank, emu
    emu.close()


def current_on(emu, bank, units=200):
    for i in (1, 2):
        assert write(emu, i, p.ADDR_TORQUE_ENABLE, 1).error == 0
        assert write(emu, i, p.ADDR_GOAL_CURRENT, units).error == 0
    assert np.all(bank.mode == MODE_CURRENT) and np.all(np.abs(bank.current_cmd) > 0)


# -- the codec ---------------------------------------------------------------------------------------------
def test_units_and_values():
    assert wd.UNIT_S == 0.020 and wd.ADDR == (98, 1)
    assert wd.units_for(wd.LEADER_PERIOD_S) == 5
    assert wd.units_for(0.021) == 2 and wd.units_for(0.020) == 1 and wd.units_for(100.0) == 127
    with pytest.raises(ValueError):
        wd.units_for(0.0)
    assert wd.period_s(5) == pytest.approx(0.1) and wd.period_s(0) is None and wd.period_s(0xFF) is None
    assert wd.describe(0xFF).startswith("-1: tripped") and wd.describe(0) == "off"
    assert wd.describe(5) == "5 x 20 ms = 100 ms"
    assert wd.supported("XL330-M288", 10) and wd.supported("XM430-W350", 38)
    assert not wd.supported("XM430-W350", 37)


def test_write_rules():
    goal = p.ADDR_GOAL_CURRENT[0]
    assert wd.write_error(b"\x10\x00", latched=True, addr=goal) == p.ERR_DATA_RANGE
    assert wd.write_error(b"\x10\x00", latched=False, addr=goal) == p.ERR_NONE
    assert wd.write_error(bytes([128]), latched=False, addr=98) == p.ERR_DATA_RANGE  # 1..127 only
    assert wd.write_error(bytes([0]), latched=True, addr=98) == p.ERR_NONE  # clearing is always allowed
    assert wd.write_error(b"\x01", latched=True, addr=p.ADDR_LED[0]) == p.ERR_NONE  # not a goal


# -- the emulated servo --------------------------------------------------------------------------------------
def test_expiry_stops_latches_and_refuses_goals(chain):
    clock, bank, emu = chain
    current_on(emu, bank)
    assert write(emu, 1, wd.ADDR, 5).error == 0 and write(emu, 2, wd.ADDR, 5).error == 0
    assert read(emu, 1, wd.ADDR, signed=True) == 5
    clock.t += 0.099
    emu.poll_watchdogs()
    assert np.all(np.abs(bank.current_cmd) > 0)  # not yet: 100 ms is the set value
    clock.t += 0.002
    emu.poll_watchdogs()
    assert np.all(bank.current_cmd == 0.0)  # stopped: no current into the operator's hand
    assert [i for i, *_ in emu.watchdog_trips] == [1, 2]
    assert emu.watchdog_trips[0][1] == pytest.approx(10.1)  # at its deadline
    assert read(emu, 1, wd.ADDR, signed=True) == -1
    assert read(emu, 1, p.ADDR_TORQUE_ENABLE) == 1  # torque stays enabled; the goal is what is refused
    assert read(emu, 1, p.ADDR_HARDWARE_ERROR_STATUS) == 0
    st = write(emu, 1, p.ADDR_GOAL_CURRENT, 300)
    assert st.error == p.ERR_DATA_RANGE and not st.error & p.ERR_ALERT_BIT
    goals = {1: p.le(300, 2), 2: p.le(300, 2)}
    prm = p.sync_write_params(*p.ADDR_GOAL_CURRENT, goals)
    emu.serve(p.build_instruction(p.BROADCAST_ID, p.INST_SYNC_WRITE, prm))
    assert np.all(bank.current_cmd == 0.0)  # a sync write's goals are refused as well
    assert write(emu, 1, wd.ADDR, 0).error == 0  # 0 clears the Bus Watchdog Error
    assert read(emu, 1, wd.ADDR, signed=True) == 0
    assert write(emu, 1, p.ADDR_GOAL_CURRENT, 300).error == 0
    assert bank.current_cmd[0] != 0.0 and bank.current_cmd[1] == 0.0  # servo 2 is still latched


def test_any_instruction_packet_feeds_it(chain):
    clock, bank, emu = chain
    current_on(emu, bank)
    write(emu, 1, wd.ADDR, 5)
    for _ in range(20):  # 1.2 s of pings (to another id) 60 ms apart: never 100 ms without a packet
        clock.t += 0.06
        status(emu, 2, p.INST_PING)
        emu.poll_watchdogs()
    assert emu.watchdog_trips == [] and bank.current_cmd[0] != 0.0
    clock.t += 0.2  # then the host goes quiet; the late packet finds the servo latched at its deadline
    st = write(emu, 1, p.ADDR_GOAL_CURRENT, 100)
    assert st.error == p.ERR_DATA_RANGE and emu.watchdog_trips[0][0] == 1


def test_silent_servo_hears_nothing(chain):
    clock, bank, emu = chain
    current_on(emu, bank)
    write(emu, 1, wd.ADDR, 5)
    emu.silent_ids = {1}  # its cable out: the host's packets do not reach it
    for _ in range(3):
        clock.t += 0.06
        status(emu, 2, p.INST_PING)
    assert emu.watchdog_trips and emu.watchdog_trips[0][0] == 1


def test_not_monitored_with_torque_off(chain):
    clock, bank, emu = chain
    write(emu, 1, wd.ADDR, 1)
    clock.t += 5.0
    emu.poll_watchdogs()
    assert emu.watchdog_trips == [] and read(emu, 1, wd.ADDR) == 1


def test_reboot_clears_it(chain):
    clock, bank, emu = chain
    current_on(emu, bank)
    write(emu, 2, wd.ADDR, 1)
    clock.t += 0.05
    emu.poll_watchdogs()
    assert read(emu, 2, wd.ADDR, signed=True) == -1
    assert status(emu, 2, p.INST_REBOOT).error == 0
    assert read(emu, 2, wd.ADDR) == 0 and read(emu, 2, p.ADDR_TORQUE_ENABLE) == 0


def test_position_mode_holds_where_it_is():
    clock = Clock()
    bank = IdealMotorBank(1, torque_constant=0.5, q0=np.array([0.3]))
    emu = DynamixelEmulator(bank, [1], "XL330-M288", emulate_return_delay=False, transport="inprocess",
                            clock=clock)
    write(emu, 1, p.ADDR_TORQUE_ENABLE, 1)
    write(emu, 1, p.ADDR_GOAL_POSITION, int(p.rad_to_ticks(1.5)))
    write(emu, 1, wd.ADDR, 2)
    bank.q[:] = 0.8  # on its way to the goal
    clock.t += 0.05
    emu.poll_watchdogs()
    assert bank.mode[0] == MODE_POSITION and bank.q_d[0] == pytest.approx(0.8, abs=2e-3)
    emu.close()


def test_old_firmware_refuses_the_write():
    bank = IdealMotorBank(2)
    emu = DynamixelEmulator(bank, [1, 2], ["XM430-W350", "XL330-M288"], emulate_return_delay=False,
                            transport="inprocess", firmware=[37, 37])
    assert write(emu, 1, wd.ADDR, 5).error == p.ERR_ACCESS  # XM430 before v38: no Bus Watchdog
    assert write(emu, 2, wd.ADDR, 5).error == 0  # every XL330 has it
    assert write(emu, 2, wd.ADDR, 200).error == p.ERR_DATA_RANGE
    emu.close()


# -- the leader driver: set at connect, read back, cleared on reconnect, re-armed after a freeze
def leader_on(emu_kw=None, model="XL330-M288"):
    from hardware.clock import LockstepClock
    from hardware.dynamixel.config import DynamixelLeaderConfig
    from hardware.dynamixel.leader import DynamixelLeader
    from hardware.types import JointLimits

    clock = LockstepClock(5.0)
    bank = IdealMotorBank(2, torque_constant=0.35, q0=np.array([0.1, -0.2]))
    emu = DynamixelEmulator(bank, [1, 2], model, emulate_return_delay=False, transport="inprocess",
                            clock=clock.now, **(emu_kw or {}))
    lim = JointLimits(q_min=np.full(2, -5.0), q_max=np.full(2, 5.0), v_max=np.full(2, 10.0),
                      tau_max=np.full(2, 0.3), tau_rate_max=np.full(2, 1e4))
    cfg = DynamixelLeaderConfig(port=emu.port_path, ids=[1, 2], signs=[1, 1], offsets_rad=[0.0, 0.0],
                                gripper_id=None, model=model, loop_hz=10.0, rx_timeout_ms=30.0)
    return clock, bank, emu, DynamixelLeader(cfg, lim, clock=clock)


def drive(clock, leader, ticks=5):
    """The loop's ticks at 500 Hz: a read and a torque, which the servos obey."""
    for _ in range(ticks):
        clock._t += 0.002
        leader.read()
        leader.command_torque(np.array([0.2, -0.2]))


def test_leader_sets_and_reads_back_the_watchdog():
    clock, bank, emu, leader = leader_on()
    leader.connect()
    try:
        assert leader.fallback.ok and leader.fallback.read_back == {1: 5, 2: 5}
        assert all(s.table[98] == 5 for s in emu.servos)
        assert "100 ms" in leader.fallback_lines()[0]
    finally:
        leader.disconnect()
        emu.close()


def test_leader_clears_a_latched_watchdog_on_connect():
    clock, bank, emu, leader = leader_on()
    s = emu.servo(2)  # a previous app crashed: the servo latched
    s.table[98], s.watchdog.latched = 0xFF, True
    leader.connect()
    try:
        assert leader.fallback.ok and not s.watchdog.latched and s.table[98] == 5
    finally:
        leader.disconnect()
        emu.close()


def test_leader_on_a_servo_that_refuses_says_what_it_means():
    clock, bank, emu, leader = leader_on({"firmware": [52, 37]}, model="XM430-W350")
    leader.connect()
    try:
        assert leader.fallback.refused.keys() == {2} and not leader.fallback.ok
        said = [w for w in leader.warnings if "Bus Watchdog not set" in w]
        assert len(said) == 1 and "id 2" in said[0] and "until its power is cut" in said[0]
        assert said[0] in leader.fallback_lines()
    finally:
        leader.disconnect()
        emu.close()


def test_leader_recovers_after_a_freeze():
    clock, bank, emu, leader = leader_on()
    leader.connect()
    try:
        drive(clock, leader)
        assert np.all(bank.current_cmd != 0)
        clock._t += 2.0  # the app is stopped (SIGSTOP) for 2 s: the servos stop by themselves
        emu.poll_watchdogs()
        assert np.all(bank.current_cmd == 0) and all(s.watchdog.latched for s in emu.servos)
        assert [t for _, t, _ in emu.watchdog_trips] == pytest.approx([clock._t - 2.0 + 0.1] * 2, abs=1e-9)
        clock._t += 0.002
        leader.read()  # the app's own watchdog zeroes the torque: that write re-arms the servos first
        assert leader._wd.rearms == 1 and all(s.table[98] == 5 and not s.watchdog.latched for s in emu.servos)
        assert write(emu, 1, p.ADDR_GOAL_CURRENT, 100).error == 0 and bank.current_cmd[0] != 0  # obeyed
    finally:
        leader.disconnect()
        emu.close()


def test_a_rested_leader_is_not_a_dead_host():
    """rest(): zero torque, then a silence by design (a lean rollout's passive leader): the servos' watchdog
    is stood down, so nothing latches and nothing says 'no force feedback'; the next command arms it again
    before its goal lands."""
    clock, bank, emu, leader = leader_on()
    leader.connect()
    try:
        drive(clock, leader)
        leader.rest("passive")
        assert np.all(bank.current_cmd == 0) and all(s.table[98] == 0 for s in emu.servos)
        clock._t += 2.0  # nothing said to the leader for 2 s
        emu.poll_watchdogs()
        assert emu.watchdog_trips == [] and not any(s.watchdog.latched for s in emu.servos)
        clock._t += 0.002
        leader.zero_torque("the end")  # the next goal write arms them first (0, then the period)
        assert all(s.table[98] == 5 and s.torque_on for s in emu.servos) and np.all(bank.current_cmd == 0)
        assert not [w for w in leader.warnings if "Bus Watchdog" in w]
        clock._t += 0.2  # armed again: a silence now is a dead host
        emu.poll_watchdogs()
        assert [i for i, *_ in emu.watchdog_trips] == [1, 2]
    finally:
        leader.disconnect()
        emu.close()
