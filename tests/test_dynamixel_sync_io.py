"""The leader's per-tick sync read / sync write (hardware/dynamixel/sync_io.py): the bytes sent are the ones
dynamixel-sdk sends, replies are parsed like the sdk parses them, and garbage never raises."""

from __future__ import annotations

import dynamixel_sdk as sdk
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.dynamixel import protocol as p
from hardware.dynamixel.fast_sync import build_fast_status
from hardware.dynamixel.sync_io import (
    SyncReadGroup,
    SyncWriteGroup,
    fast_sync_read,
    plain_sync_read,
    write_only,
)

IDS, ADDR, LEN = [1, 2, 5, 9], 126, 10


class ScriptedPort:
    """A port whose reads return scripted chunks (one per readPort call, at most the length asked for);
    the packet timeout has passed once the script is used up."""

    def __init__(self, chunks=()):
        self.chunks = [bytearray(c) for c in chunks]
        self.sent: list[bytes] = []
        self.is_using = False
        self.cleared = 0

    def clearPort(self):  # noqa: N802
        self.cleared += 1

    def writePort(self, packet):  # noqa: N802
        self.sent.append(bytes(packet))
        return len(packet)

    def setPacketTimeoutMillis(self, ms):  # noqa: N802
        pass

    setPacketTimeout = setPacketTimeoutMillis  # noqa: N815 -- the sdk's tx side calls it

    def isPacketTimeout(self):  # noqa: N802
        return not self.chunks

    def getBytesAvailable(self):  # noqa: N802
        return len(self.chunks[0]) if self.chunks else 0

    def readPort(self, n):  # noqa: N802
        if not self.chunks:
            return b""
        out = bytes(self.chunks[0][:n])
        del self.chunks[0][:n]
        if not self.chunks[0]:
            self.chunks.pop(0)
        return out


def _blocks(err4=0):
    return [(i, err4 if i == 9 else 0, bytes((i * 7 + k) & 0xFF for k in range(LEN))) for i in IDS]


def test_instruction_bytes_are_the_sdks():
    port, ph = ScriptedPort(), sdk.PacketHandler(2.0)
    g = sdk.GroupSyncRead(port, ph, ADDR, LEN)
    for i in IDS:
        g.addParam(i)
    g.txPacket()
    port.is_using = False
    g.fastSyncReadTxPacket()
    port.is_using = False
    values = {1: b"\xff\xff", 2: b"\xfd\x00", 5: b"\x10\x00", 9: b"\xf0\xff"}  # FF FF FD: sdk stuffs it
    w = sdk.GroupSyncWrite(port, ph, 102, 2)
    for i, d in values.items():
        w.addParam(i, list(d))
    w.txPacket()
    ours = SyncReadGroup(IDS, ADDR, LEN)
    assert port.sent == [ours.plain_packet, ours.fast_packet, SyncWriteGroup(IDS, 102, 2).packet(values)]


def test_sync_write_refuses_what_is_not_in_its_group_and_a_busy_port():
    g = SyncWriteGroup([1, 2], 102, 2)
    for bad in ({3: b"\x00\x00"}, {1: b"\x00"}):
        try:
            g.packet(bad)
        except ValueError:
            continue
        raise AssertionError(f"accepted {bad}")
    port = ScriptedPort()
    port.is_using = True
    assert not write_only(port, g.packet({1: b"\x01\x00"})) and not port.sent


def test_fast_reply_after_garbage_in_pieces():
    g = SyncReadGroup(IDS, ADDR, LEN)
    reply = build_fast_status(_blocks(err4=p.ERR_ALERT_BIT), LEN)
    port = ScriptedPort([b"\x00\xff\xff\xfd", b"\x00\x01garbage\xff", reply[:9], reply[9:30], reply[30:]])
    got = fast_sync_read(port, g, 5.0)
    assert got == {i: (d, e) for i, e, d in _blocks(err4=p.ERR_ALERT_BIT)}
    assert not port.is_using and port.sent == [g.fast_packet]


def test_fast_reply_cut_short_or_corrupt_gives_intact_blocks():
    g = SyncReadGroup(IDS, ADDR, LEN)
    reply = bytearray(build_fast_status(_blocks(), LEN))
    assert set(fast_sync_read(ScriptedPort([reply[:40]]), g, 5.0)) == {1, 2}  # block 3 ends at byte 42
    reply[8 + 2 * 14 + 5] ^= 0x40  # a data byte of the third block
    assert set(fast_sync_read(ScriptedPort([reply]), g, 5.0)) == {1, 2}
    assert fast_sync_read(ScriptedPort([]), g, 5.0) == {}


def test_plain_reply_stuffed_and_with_an_error_status():
    g = SyncReadGroup(IDS, ADDR, LEN)
    data = {i: (b"\xff\xff\xfd" + bytes(7)) if i == 1 else bytes([i] * LEN) for i in IDS}
    wire = b"".join(p.build_status(i, 0x02 if i == 5 else 0, data[i] if i != 5 else b"") for i in IDS)
    assert b"\xff\xff\xfd\xfd" in wire
    got = plain_sync_read(ScriptedPort([wire[:13], wire[13:]]), g, 5.0)
    assert got == {i: (data[i], 0) for i in IDS if i != 5}  # servo 5 answered an error: no data


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=80), max_size=6), st.booleans())
def test_garbage_never_raises(chunks, fast):
    g = SyncReadGroup(IDS, ADDR, LEN)
    port = ScriptedPort(chunks)
    got = (fast_sync_read if fast else plain_sync_read)(port, g, 5.0)
    assert set(got) <= set(IDS) and not port.is_using


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 0xFFFF))
def test_crc16_two_bytes_per_lookup_equals_the_bytewise_definition(data, init):
    crc = init
    for b in data:  # the e-manual's table algorithm, one byte at a time
        crc = ((crc << 8) ^ p._CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    assert p.crc16(data, init) == crc == p.crc16(bytearray(data), init)
