"""Protocol 2.0 codec: golden bytes from the ROBOTIS e-manual, round trips, garbage robustness."""

from __future__ import annotations

import math

import dynamixel_sdk as sdk
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.dynamixel import protocol as p

PING_ID1 = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
# e-manual: ping reply of id 1, XM430-W210 (model 1030 = 0x0406), firmware 0x26
PING_REPLY_ID1 = bytes.fromhex("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")
# e-manual: read of id 1, address 132 (present position), 4 bytes
READ_ID1 = bytes.fromhex("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")


def test_golden_ping_instruction():
    assert p.build_instruction(1, p.INST_PING) == PING_ID1
    assert p.crc16(PING_ID1[:-2]) == 0x4E19


def test_golden_read_and_status():
    assert p.build_instruction(1, p.INST_READ, p.read_params(132, 4)) == READ_ID1
    assert p.build_status(1, 0, p.le(1030, 2) + bytes([0x26])) == PING_REPLY_ID1
    (pkt,) = p.parse_packets(PING_REPLY_ID1)
    assert pkt.is_status and pkt.id == 1 and pkt.error == 0 and pkt.params == bytes([0x06, 0x04, 0x26])


def test_crc_matches_dynamixel_sdk():
    ph = sdk.PacketHandler(2.0)
    rng = np.random.default_rng(0)
    for _ in range(50):
        data = rng.integers(0, 256, rng.integers(1, 60)).tolist()
        assert p.crc16(bytes(data)) == ph.updateCRC(0, data, len(data))


def test_stuffing_golden():
    assert p.stuff(b"\x03\xff\xff\xfd\x01") == b"\x03\xff\xff\xfd\xfd\x01"
    assert p.unstuff(b"\x03\xff\xff\xfd\xfd\x01") == b"\x03\xff\xff\xfd\x01"
    pkt = p.build_instruction(1, p.INST_WRITE, b"\x74\x00\xff\xff\xfd\x00")
    assert pkt[5] == 10  # LEN counts the stuffed byte: 1 inst + 6 params + 1 stuffing + 2 crc
    (back,) = p.parse_packets(pkt)
    assert back.params == b"\x74\x00\xff\xff\xfd\x00"


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=64))
def test_stuff_roundtrip(body):
    s = p.stuff(body)
    assert p.unstuff(s) == body
    assert b"\xff\xff\xfd" not in s.replace(b"\xff\xff\xfd\xfd", b"")


@settings(max_examples=200, deadline=None)
@given(
    st.integers(0, 252),
    st.sampled_from(sorted(p.KNOWN_INSTRUCTIONS - {p.INST_STATUS})),
    st.binary(max_size=40),
)
def test_instruction_roundtrip(dxl_id, inst, params):
    (pkt,) = p.parse_packets(p.build_instruction(dxl_id, inst, params))
    assert (pkt.id, pkt.instruction, pkt.params) == (dxl_id, inst, params)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 252), st.integers(0, 255), st.binary(max_size=40), st.integers(1, 7))
def test_status_roundtrip_split_feeds(dxl_id, err, params, chunk):
    raw = p.build_status(dxl_id, err, params) * 2
    parser = p.PacketParser()
    got = []
    for i in range(0, len(raw), chunk):
        got += parser.feed(raw[i : i + chunk])
    assert [(q.id, q.error, q.params) for q in got] == [(dxl_id, err, params)] * 2
    assert parser.errors == 0 and parser.garbage_bytes == 0


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.binary(max_size=40))
def test_garbage_never_raises_and_resyncs(garbage, params):
    parser = p.PacketParser()
    good = p.build_instruction(3, p.INST_WRITE, params)
    parser.feed(garbage)
    parser.discard_partial()  # garbage may end in a plausible header: the rx timeout drops it
    got = parser.feed(good)
    assert got and got[-1].params == params


def test_counters():
    parser = p.PacketParser()
    good = p.build_instruction(1, p.INST_PING)
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    unknown = p._frame(1, b"\x77")
    bad_len = p.HEADER + b"\x01\x01\x00\x01\x00\x00"
    got = parser.feed(b"junk" + bytes(bad_crc) + unknown + bad_len + good)
    assert len(got) == 1 and got[0].instruction == p.INST_PING
    assert parser.bad_crc == 1 and parser.unknown_instruction == 1 and parser.bad_length == 1
    assert parser.garbage_bytes >= 4


def test_units():
    assert math.isclose(p.ticks_to_rad(4096), 2 * math.pi)
    assert p.rad_to_ticks(math.pi) == 2048
    assert math.isclose(p.velocity_units_to_rad_s(1), 0.229 * 2 * math.pi / 60)
    assert p.rad_s_to_velocity_units(p.velocity_units_to_rad_s(-37)) == -37
    assert p.to_signed(0xFFFF, 2) == -1 and p.to_signed(0x7FFF, 2) == 32767
    assert p.to_signed(0xFFFFFFFE, 4) == -2
    assert list(p.to_signed(np.array([0xFFFF, 1]), 2)) == [-1, 1]
    assert p.to_unsigned(-1, 2) == 0xFFFF
    assert math.isclose(float(p.current_units_to_amps(100, 0.00269)), 0.269)
    assert list(p.amps_to_current_units([5.0, -5.0, np.nan], 0.001, 1750)) == [1750, -1750, 0]


@given(st.integers(-(2**31), 2**31 - 1))
def test_signed_roundtrip(v):
    assert p.to_signed(p.to_unsigned(v, 4), 4) == v
    assert p.from_le(p.le(v, 4), signed=True) == v
