"""Fast Sync Read (0x8A): the emulator's one-packet reply through dynamixel-sdk, the leader's choice of it at
connect (and its fallback), and failed reads on damaged replies (SIMULATED chain, in-process port)."""

from __future__ import annotations

import dynamixel_sdk as sdk
import numpy as np
import pytest

from hardware.dynamixel import protocol as p
from hardware.dynamixel.bus import DynamixelBus
from hardware.dynamixel.config import DynamixelLeaderConfig
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.dynamixel.fast_sync import (
    build_fast_status,
    choose_fast_sync_read,
    fast_status_len,
    fast_sync_read_bytes,
    plain_sync_read_bytes,
    split_fast_status,
)
from hardware.dynamixel.leader import DynamixelLeader
from hardware.errors import ConfigError, DeviceError
from hardware.sim.motors import IdealMotorBank
from hardware.types import STATUS_STALE, JointLimits

IDS = [1, 2, 3, 4]
FIELD = (p.FEEDBACK_START, p.FEEDBACK_LEN)


def _limits(n=4):
    return JointLimits(q_min=np.full(n, -10.0), q_max=np.full(n, 10.0), v_max=np.full(n, 10.0),
                       tau_max=np.full(n, 0.4), tau_rate_max=np.full(n, 1e4))


def _emu(firmware=52, n=4):
    bank = IdealMotorBank(n, q0=np.linspace(-2.5, 3.0, n))
    return bank, DynamixelEmulator(bank, IDS[:n], "XL330-M288", return_delay=0, emulate_return_delay=False,
                                   transport="inprocess", firmware=firmware, clock=lambda: 1.0)


def _leader(emu, **kw):
    cfg = DynamixelLeaderConfig(port=emu.port_path, ids=IDS, signs=[1, -1, 1, -1],
                                offsets_rad=[0.3, 4.0, -2.5, 7.0], loop_hz=10.0, **kw)
    return DynamixelLeader(cfg, _limits())


def _bus(emu):
    bus = DynamixelBus(emu.port_path, 4_000_000)
    bus.open()
    return bus


def test_packet_layout_and_sizes():
    blocks = [(1, 0, bytes(range(10))), (7, 0x80, b"\xff\xff\xfd" + bytes(7))]
    pkt = build_fast_status(blocks, 10)
    assert pkt[:8] == p.HEADER + bytes([0xFE, 29, 0, p.INST_STATUS])  # LEN = 1 + 2 * (10 + 4)
    assert len(pkt) == 7 + fast_status_len(2, 10) == fast_sync_read_bytes(2, 10) - 14 - 2
    assert p.crc16(pkt[:-2]) == pkt[-2] | (pkt[-1] << 8)  # the last running CRC is the packet CRC
    assert p.crc16(pkt[:20]) == pkt[20] | (pkt[21] << 8)  # block 1's CRC: every byte before it
    assert b"\xff\xff\xfd\xfd" not in pkt  # not stuffed
    assert split_fast_status(pkt, [1, 7], 10, True) == {1: (bytes(range(10)), 0), 7: (blocks[1][2], 0x80)}
    assert split_fast_status(pkt, [1, 7], 10, False) == split_fast_status(pkt, [1, 7], 10, True)
    assert split_fast_status(pkt, [7, 1], 10, True) == {}  # another id list's packet
    assert fast_sync_read_bytes(4, 10) < plain_sync_read_bytes(4, 10) == 14 + 4 + 4 * 21


def test_fast_and_plain_read_identical_bytes_and_the_sdk_parses_the_reply():
    bank, emu = _emu()
    with emu:
        bus = _bus(emu)
        grp = bus.make_sync_read(IDS, FIELD)
        # current -1 unit, velocity -3 units: data holds FF FF FD, which a stuffed reply would corrupt
        bank.tau_motor[:] = [-0.001, 0.5, -0.7, 0.0]
        bank.q_dot[:] = np.array([-3, 70000, -1, 0]) * p.RAD_S_PER_VELOCITY_UNIT
        emu.set_hardware_error(4, 1 << 5)  # the alert bit travels in its block's error byte
        for q in (np.linspace(-2.5, 3.0, 4), np.array([100.0, -100.0, 0.0, 1e-4])):
            bank.q[:] = q
            plain = bus.sync_read(grp, IDS, 20.0)
            fast = bus.sync_read(grp, IDS, 20.0, fast=True)
            assert len(plain) == 4 and fast == plain
            assert b"\xff\xff\xfd" in plain[1][0] and fast[4][1] & p.ERR_ALERT_BIT
            sdk_grp = sdk.GroupSyncRead(bus.port, bus.ph, *FIELD)  # dynamixel-sdk's own host side
            for i in IDS:
                sdk_grp.addParam(i)
            assert sdk_grp.fastSyncRead() == 0
            assert {i: bytes(sdk_grp.data_dict[i]) for i in IDS} == {i: d for i, (d, _) in plain.items()}
        bus.close()


def test_leader_reads_the_same_state_fast_and_plain():
    bank, emu = _emu()
    with emu, _leader(emu) as leader:
        assert leader.fast_read and not leader.warnings
        assert leader.rx_timeout_ms == leader.bus.rx_timeout_ms(fast_sync_read_bytes(4, 10), 4)
        bank.q[:] += [0.4, -0.2, 0.1, 0.05]
        bank.q_dot[:] = [0.3, -1.0, 0.0, 2.0]
        bank.tau_motor[:] = [0.01, -0.02, 0.0, 0.3]
        fast = leader.read()
        leader.fast_read = False
        plain = leader.read()
        for f in ("q", "q_dot", "current", "tau_m", "status"):
            np.testing.assert_array_equal(getattr(fast, f), getattr(plain, f))
        assert not np.any(fast.status & STATUS_STALE)


def test_old_firmware_falls_back_and_says_so_once():
    _, emu = _emu(firmware=[52, 52, 44, 52])
    with emu:
        with _leader(emu) as leader:
            assert not leader.fast_read
            assert leader.warnings == ["leader leader: fast sync read not supported by servo 3 "
                                       "(firmware v44, needs v45): plain sync read"]
            assert not np.any(leader.read().status & STATUS_STALE)
        with pytest.raises(DeviceError, match="fast sync read not supported by servo 3"):
            _leader(emu, fast_sync_read=True).connect()
        with _leader(emu, fast_sync_read=False) as leader:
            assert not leader.fast_read and not leader.warnings
        # firmware not known: the probe finds the servo whose block is missing
        bus = _bus(emu)
        grp = bus.make_sync_read(IDS, FIELD)
        fast, why = choose_fast_sync_read("auto", bus, grp, IDS, 20.0, {})
        assert not fast and why.startswith("servo 3 (firmware v-1; no valid fast reply")
        assert set(bus.sync_read(grp, IDS, 20.0, fast=True)) == {1, 2}  # intact blocks before the hole
        bus.close()
    with pytest.raises(ConfigError, match="fast_sync_read is 'yes'"):
        _leader(emu, fast_sync_read="yes")


def test_silent_servos_leave_holes():
    _, emu = _emu()
    with emu:
        bus = _bus(emu)
        grp = bus.make_sync_read(IDS, FIELD)
        emu.silent_ids = {3}
        assert set(bus.sync_read(grp, IDS, 20.0, fast=True)) == {1, 2}
        emu.silent_ids = {1}  # nobody sends the header
        assert bus.sync_read(grp, IDS, 20.0, fast=True) == {}
        bus.close()


def _flip(k):
    return lambda b: b[:k] + bytes([b[k] ^ 0x01]) + b[k + 1 :]


BLOCK = 8 + 14  # header, then block 1 (ERR ID DATA10 CRC2): block 2 starts here
CORRUPTIONS = {
    "block 2 CRC": (_flip(BLOCK + 12), {1}),
    "block 3 data": (_flip(BLOCK + 14 + 5), {1, 2}),
    "packet CRC": (_flip(-1), {1, 2, 3}),
    "truncated": (lambda b: b[:-9], {1, 2, 3}),
    "cut in the header": (lambda b: b[:6], set()),
    "garbage": (lambda b: bytes(np.random.default_rng(5).integers(0, 256, len(b), dtype=np.uint8)), set()),
    "wrong LEN": (lambda b: b[:5] + bytes([b[5] + 1]) + b[6:], set()),
    "plain status": (lambda b: p.build_status(1, 0, bytes(10)), set()),
    "nothing": (lambda b: b"", set()),
}


@pytest.mark.parametrize("name", list(CORRUPTIONS))
def test_damaged_reply_is_a_failed_read_not_an_exception(name):
    mangle, intact = CORRUPTIONS[name]
    bank, emu = _emu()
    serve = emu.serve
    damage = {"on": False}

    def damaged(data, rate=None):
        out = serve(data, rate)
        return mangle(out) if damage["on"] and data[7] == p.INST_FAST_SYNC_READ else out

    emu.serve = damaged
    with emu, _leader(emu) as leader:
        assert leader.fast_read
        before = leader.read()
        bank.q[:] += 0.05
        damage["on"] = True
        got = leader.bus.sync_read(leader._read_group, IDS, leader.rx_timeout_ms, fast=True)
        assert set(got) == intact
        st = leader.read()
        assert leader.lost_reads == 1
        stale = (st.status & STATUS_STALE) != 0
        assert list(stale) == [i not in intact for i in IDS]
        np.testing.assert_array_equal(st.q[stale], before.q[stale])  # stale joints keep the last sample
        damage["on"] = False
        assert not np.any(leader.read().status & STATUS_STALE)


def test_split_never_raises_and_never_returns_damaged_blocks():
    rng = np.random.default_rng(0)
    blocks = [(i, 0, bytes(rng.integers(0, 256, 10, dtype=np.uint8))) for i in IDS]
    good = build_fast_status(blocks, 10)
    truth = {i: (d, 0) for i, _, d in blocks}
    for _ in range(3000):
        b = bytearray(good)
        for _ in range(int(rng.integers(1, 4))):
            b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
        cut = bytes(b[: int(rng.integers(0, len(b) + 1))])
        for pkt in (bytes(b), cut, bytes(rng.integers(0, 256, int(rng.integers(0, 80)), dtype=np.uint8))):
            got = split_fast_status(pkt, IDS, 10, False)
            assert all(truth[i] == v for i, v in got.items())
