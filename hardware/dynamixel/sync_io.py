"""The leader's two per-tick transactions (sync read, sync write) built and parsed with this package's codec.

Why not dynamixel-sdk's GroupSyncRead / GroupSyncWrite for these two: the sdk builds every packet as a list
of Python ints, byte-stuffs and checksums it byte by byte, and rebuilds the constant sync read instruction
each tick -- measured 100+ us of the loop's 2 ms tick on a 2-vCPU VM (issue #24, bench/profile_tick.py).
Here the sync read instruction is built once (it never changes), the sync write is framed by
protocol.build_instruction (the codec the emulator and the tests use: one source for the wire format) and
replies are parsed by protocol.PacketParser / fast_sync.split_fast_status. The bytes on the wire are the
ones the sdk would send (tests/test_dynamixel_sync_io.py compares them); the sdk still opens the port and
runs every other transaction (ping, read, write).

A transaction holds the port's `is_using` flag as the sdk's do, so DynamixelBus._ready() recovers a port
left busy by Ctrl-C the same way. Receiving spins on port.readPort() until the reply is complete or the
port's packet timeout passes, exactly like the sdk's rxPacket.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from hardware.dynamixel import protocol as p
from hardware.dynamixel.fast_sync import _FAST_PREFIX, FAST_HEADER_LEN, fast_status_len, split_fast_status


@dataclass
class SyncReadGroup:
    """One sync read of `length` bytes from `address` on servos `ids` (in this order); instruction packets
    for the plain (0x82) and fast (0x8A) variants, built once."""

    ids: list[int]
    address: int
    length: int
    plain_packet: bytes = field(init=False, repr=False)
    fast_packet: bytes = field(init=False, repr=False)
    fast_reply_len: int = field(init=False, repr=False)  # bytes of the fast reply (header + LEN; not stuffed)

    def __post_init__(self) -> None:
        self.ids = [int(i) for i in self.ids]
        params = p.sync_read_params(self.address, self.length, self.ids)
        self.plain_packet = p.build_instruction(p.BROADCAST_ID, p.INST_SYNC_READ, params)
        self.fast_packet = p.build_instruction(p.BROADCAST_ID, p.INST_FAST_SYNC_READ, params)
        self.fast_reply_len = 7 + fast_status_len(len(self.ids), self.length)  # made once: read every tick

    @property
    def data_length(self) -> int:  # the sdk group's name (fast_sync.py and older callers use it)
        return self.length


@dataclass
class SyncWriteGroup:
    """One sync write of `length` bytes to `address` on servos `ids`."""

    ids: list[int]
    address: int
    length: int
    _int_packet: struct.Struct | None = field(default=None, init=False, repr=False, compare=False)
    _int_args: list = field(default_factory=list, init=False, repr=False, compare=False)

    def packet(self, values: dict[int, bytes]) -> bytes:
        """The instruction for values {id: `length` bytes}; ids outside the group are refused."""
        for i, d in values.items():
            if i not in self.ids or len(d) != self.length:
                raise ValueError(f"sync write: servo {i} with {len(d)} bytes is not in this group "
                                 f"({self.ids}, {self.length} bytes each)")
        return p.build_instruction(p.BROADCAST_ID, p.INST_SYNC_WRITE,
                                   p.sync_write_params(self.address, self.length, values))


    def packet_ints(self, values) -> bytes:
        """The instruction for one signed integer per servo, in the group's id order (the per-tick goal
        current). Values must fit `length` bytes. The whole packet but its CRC in one struct.pack from a
        template made once per group (header, LEN, instruction, address, ids); the bytes
        protocol.build_instruction frames, and framed by it where the body would need byte stuffing."""
        if self._int_packet is None:
            n = len(self.ids)
            body = 1 + 4 + (1 + self.length) * n  # INST, address and length, (id, value) per servo
            self._int_packet = struct.Struct(f"<4sBHBHH{('B' + _INT_FORMATS[self.length]) * n}")
            self._int_args = [p.HEADER, p.BROADCAST_ID, body + 2, p.INST_SYNC_WRITE, self.address,
                              self.length, *[x for i in self.ids for x in (i, 0)]]
        args = self._int_args.copy()  # a copy: a watchdog's write on another thread must not see these
        args[7::2] = values  # one per id (a count that differs raises, as the zip(strict) did)
        pkt = self._int_packet.pack(*args)
        if pkt.find(b"\xff\xff\xfd", 7) >= 0:  # the body needs stuffing: the general framing
            return p.build_instruction(p.BROADCAST_ID, p.INST_SYNC_WRITE, pkt[8:])
        c = p.crc16(pkt)
        return pkt + bytes((c & 0xFF, c >> 8))


_INT_FORMATS = {1: "b", 2: "h", 4: "i"}  # struct codes of a signed field of 1, 2, 4 bytes


def _begin(port, packet: bytes, flush: bool = True) -> bool:
    """Claim the port, drop stale bytes (flush), send packet; False (port released) if busy or short."""
    if port.is_using:
        return False
    port.is_using = True
    if flush:
        port.clearPort()
    if port.writePort(packet) != len(packet):
        port.is_using = False
        return False
    return True


def write_only(port, packet: bytes) -> bool:
    """Send an instruction that has no reply (a sync write). Stale input bytes stay: they are no reply to
    this, and the next read's transaction drops them (a flush is a syscall on the loop's every tick)."""
    if not _begin(port, packet, flush=False):
        return False
    port.is_using = False
    return True


def fast_sync_read(port, group: SyncReadGroup, timeout_ms: float) -> dict[int, tuple[bytes, int]]:
    """{id: (data, error byte)} from one Fast Sync Read; a reply cut short or corrupt gives the intact blocks
    before the damage, garbage gives {} (never raises)."""
    buf, intact = fast_sync_read_reply(port, group, timeout_ms)
    if len(buf) < FAST_HEADER_LEN:
        return {}
    return split_fast_status(bytes(buf), group.ids, group.length, crc_checked=intact)


def fast_sync_read_reply(port, group: SyncReadGroup, timeout_ms: float) -> tuple[bytearray, bool]:
    """(the reply's bytes, intact) of one Fast Sync Read: intact when it is the whole reply and its last CRC,
    which runs over every byte before it, checks -- then its layout and ids are still unchecked
    (split_fast_status, or the leader's decode straight from the bytes: leader_math.FastReplyDecoder).
    Nothing or garbage gives a short or not-intact buffer (never raises)."""
    # no input flush after a whole reply (BufferedPortHandler.rx_clean: a syscall a tick on a real port)
    if not _begin(port, group.fast_packet, flush=not getattr(port, "rx_clean", False)):
        return bytearray(), False
    try:
        port.setPacketTimeoutMillis(timeout_ms)
        want, buf = group.fast_reply_len, bytearray()
        while True:
            buf += port.readPort(want - len(buf))
            i = buf.find(_FAST_PREFIX)
            if i != 0:  # bytes before the reply's header (an echo, line noise); keep a possible partial one
                del buf[: i if i > 0 else max(len(buf) - len(_FAST_PREFIX) + 1, 0)]
            if len(buf) >= want or port.isPacketTimeout():
                break
    finally:
        port.is_using = False
    # the last block's CRC runs over every byte before it: one check for the usual intact reply; the block
    # by block walk (intact blocks before a damage) only when it fails
    intact = len(buf) == want and p.crc16(buf[:-2]) == buf[-2] | (buf[-1] << 8)
    if intact and hasattr(port, "mark_clean"):
        port.mark_clean()
    return buf, intact


def plain_sync_read(port, group: SyncReadGroup, timeout_ms: float) -> dict[int, tuple[bytes, int]]:
    """{id: (data, error byte)} for the servos whose status packet came intact before the timeout. A status
    with an error number carries no data and is left out, as the sdk's readRx does."""
    if not _begin(port, group.plain_packet):
        return {}
    out: dict[int, tuple[bytes, int]] = {}
    parser = p.PacketParser()
    per_status = 11 + group.length
    try:
        port.setPacketTimeoutMillis(timeout_ms)
        wanted = set(group.ids)
        while True:
            # stuffing can lengthen a status packet: take whatever is waiting, at least what is still due
            chunk = port.readPort(max(per_status * (len(wanted) - len(out)), port.getBytesAvailable()))
            for pkt in parser.feed(chunk) if chunk else ():
                if (pkt.is_status and pkt.id in wanted and len(pkt.params) == group.length
                        and not pkt.error & 0x7F):
                    out[pkt.id] = (pkt.params, pkt.error)
            if len(out) == len(wanted) or port.isPacketTimeout():
                break
    finally:
        port.is_using = False
    return out
