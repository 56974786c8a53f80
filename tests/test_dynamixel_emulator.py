"""The Dynamixel emulator over a raw pty (no sdk): control table, access rules, bank effects, faults."""

from __future__ import annotations

import os
import select
import time

import numpy as np
import pytest

from hardware.dynamixel import protocol as p
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.dynamixel.models import MODELS, get_model, resolve_models
from hardware.errors import ConfigError
from hardware.sim.motors import MODE_CURRENT, MODE_DISABLED, MODE_POSITION, IdealMotorBank


class Wire:
    """A raw client on the emulator's pty."""

    def __init__(self, path):
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        self.parser = p.PacketParser()

    def send(self, dxl_id, inst, params=b""):
        os.write(self.fd, p.build_instruction(dxl_id, inst, params))

    def recv(self, n=1, timeout=1.0):
        got, deadline = [], time.monotonic() + timeout
        while len(got) < n and time.monotonic() < deadline:
            r, _, _ = select.select([self.fd], [], [], 0.01)
            if r:
                got += self.parser.feed(os.read(self.fd, 4096))
        return got

    def txrx(self, dxl_id, inst, params=b"", timeout=1.0):
        self.send(dxl_id, inst, params)
        got = self.recv(1, timeout)
        return got[0] if got else None

    def write(self, dxl_id, field, value):
        return self.txrx(dxl_id, p.INST_WRITE, p.le(field[0], 2) + p.le(value, field[1]))

    def read(self, dxl_id, field, signed=False):
        r = self.txrx(dxl_id, p.INST_READ, p.read_params(*field))
        return p.from_le(r.params, signed)


@pytest.fixture
def rig():
    bank = IdealMotorBank(2, torque_constant=0.5, q0=np.array([0.5, -0.25]))
    emu = DynamixelEmulator(
        bank,
        [1, 2],
        ["XL330-M288", "XM430-W350"],
        signs=[1, -1],
        offsets_rad=[0.0, 3.0],
        emulate_return_delay=False,
        seed=0,
    )
    wire = Wire(emu.port_path)
    yield bank, emu, wire
    os.close(wire.fd)
    emu.close()


def test_models_table():
    m = get_model("xl330-m288-t")
    assert m.model_number == 1200 and abs(m.torque_constant - 0.52 / 1.47) < 1e-12
    assert MODELS["XM430-W350"].amps_per_unit == 0.00269 and MODELS["XC330-M288"].model_number == 1240
    assert abs(MODELS["XC330-T288"].default_goal_current_units_per_nm - 1158.73) < 1e-9
    assert len(resolve_models("XL330-M077", 3)) == 3
    with pytest.raises(ConfigError):
        get_model("XL999")
    with pytest.raises(ConfigError):
        resolve_models(["XL330-M288"], 2)


def test_ping_and_present_values(rig):
    bank, emu, wire = rig
    r = wire.txrx(2, p.INST_PING)
    assert r.error == 0 and p.from_le(r.params[:2]) == 1020
    assert 0 <= wire.read(1, p.ADDR_PRESENT_POSITION) < 4096  # power-on: within one turn
    ticks2 = wire.read(2, p.ADDR_PRESENT_POSITION, signed=True)
    assert abs(p.ticks_to_rad(ticks2) - 3.25) < 2e-3  # servo angle = sign * q + offset = 0.25 + 3.0
    servo = emu.servo(2)
    assert abs(servo.joint_angle(ticks2) - (-0.25)) < 2e-3
    assert wire.txrx(9, p.INST_PING, timeout=0.1) is None  # absent id: silence


def test_eeprom_access_and_current_mode(rig):
    bank, emu, wire = rig
    assert wire.write(1, p.ADDR_OPERATING_MODE, p.OP_MODE_CURRENT).error == 0
    assert wire.write(1, p.ADDR_TORQUE_ENABLE, 1).error == 0
    assert wire.write(1, p.ADDR_OPERATING_MODE, p.OP_MODE_POSITION).error == p.ERR_ACCESS
    assert wire.write(1, p.ADDR_MODEL_NUMBER, 5).error == p.ERR_ACCESS  # read-only
    assert wire.write(1, p.ADDR_GOAL_CURRENT, 200).error == 0
    assert bank.mode[0] == MODE_CURRENT and abs(bank.current_cmd[0] - 0.2) < 1e-12
    assert wire.write(1, p.ADDR_GOAL_CURRENT, 5000).error == p.ERR_DATA_RANGE  # above Current Limit(38)
    assert wire.write(1, p.ADDR_TORQUE_ENABLE, 0).error == 0
    assert bank.mode[0] == MODE_DISABLED


def test_position_mode_and_sign(rig):
    bank, emu, wire = rig
    wire.write(2, p.ADDR_TORQUE_ENABLE, 1)  # factory mode 3: holds where it is
    assert bank.mode[1] == MODE_POSITION and abs(bank.q_d[1] - (-0.25)) < 2e-3
    base = emu.servo(2).turn_base
    goal = int(p.rad_to_ticks(-1 * 0.4 + 3.0)) + base
    wire.write(2, p.ADDR_GOAL_POSITION, goal)
    assert abs(bank.q_d[1] - 0.4) < 2e-3


def test_sync_write_lands_after_drain_and_sync_read(rig):
    bank, emu, wire = rig
    for i in (1, 2):
        wire.write(i, p.ADDR_OPERATING_MODE, 0)
        wire.write(i, p.ADDR_TORQUE_ENABLE, 1)
    for k in range(20):
        os.write(
            wire.fd,
            p.build_instruction(
                p.BROADCAST_ID,
                p.INST_SYNC_WRITE,
                p.sync_write_params(102, 2, {1: p.le(k, 2), 2: p.le(-k, 2)}),
            ),
        )
        assert emu.drain(1.0)
        assert abs(bank.current_cmd[0] - k * 0.001) < 1e-12
        assert abs(bank.current_cmd[1] - k * 0.00269) < 1e-12  # sign -1 servo, -k units
    wire.send(p.BROADCAST_ID, p.INST_SYNC_READ, p.sync_read_params(126, 10, [2, 1]))
    got = wire.recv(2)
    assert [g.id for g in got] == [2, 1] and all(len(g.params) == 10 for g in got)
    wire.send(
        p.BROADCAST_ID,
        p.INST_BULK_READ,
        bytes([1]) + p.read_params(146, 1) + bytes([2]) + p.read_params(0, 2),
    )
    got = wire.recv(2)
    assert got[0].params == bytes([30]) and p.from_le(got[1].params) == 1020


def test_faults_drop_silent_garbage_reboot(rig):
    bank, emu, wire = rig
    os.write(wire.fd, b"\xff\xff\xfd\x00garbage\x00\x01" + bytes(range(256)))
    time.sleep(0.08)  # past the emulator's partial-packet timeout
    assert emu.drain(1.0)
    assert wire.txrx(1, p.INST_PING) is not None  # still serving
    emu.drop_prob = 1.0
    assert wire.txrx(1, p.INST_PING, timeout=0.1) is None and emu.dropped >= 1
    emu.drop_prob = 0.0
    emu.set_silent(True)
    assert wire.txrx(1, p.INST_PING, timeout=0.1) is None
    emu.set_silent(False)
    wire.write(1, p.ADDR_TORQUE_ENABLE, 1)
    assert wire.txrx(1, p.INST_REBOOT).error == 0
    assert wire.read(1, p.ADDR_TORQUE_ENABLE) == 0 and bank.mode[0] == MODE_DISABLED
    assert emu.parser.garbage_bytes > 0


def test_generic_sync_write_goal_position(rig):
    bank, emu, wire = rig
    wire.write(1, p.ADDR_TORQUE_ENABLE, 1)  # position mode (factory)
    base = emu.servo(1).turn_base
    goal = int(p.rad_to_ticks(0.9)) + base
    os.write(wire.fd, p.build_instruction(p.BROADCAST_ID, p.INST_SYNC_WRITE,
                                          p.sync_write_params(116, 4, {1: p.le(goal, 4)})))
    assert emu.drain(1.0)
    assert bank.mode[0] == MODE_POSITION and abs(bank.q_d[0] - 0.9) < 2e-3
