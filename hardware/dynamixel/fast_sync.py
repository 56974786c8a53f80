"""Fast Sync Read (Protocol 2.0 instruction 0x8A): the one status packet of a whole chain, and its sizes.

Wire layout of the reply (ROBOTIS e-manual, Protocol 2.0 "Fast Sync Read"; what dynamixel-sdk's
GroupSyncRead.fastSyncReadRxPacket parses):
    FF FF FD 00 | FE | LEN_L LEN_H | 55 | ERR1 ID1 DATA1 CRC1 | ERR2 ID2 DATA2 CRC2 | ... | ERRn IDn ... CRCn
LEN = 1 + n * (L + 4). The servos answer in the order of the instruction's id list, each in its own time
slot: the first one sends the header, each appends its block and the CRC-16 of every byte on the wire so
far (a running CRC), so the last block's CRC is the packet CRC. The packet is not byte-stuffed (the first
servo fixes LEN before the others speak; the sdk's rxPacket(fast_option=True) skips unstuffing).
Firmware before v45 does not know the instruction: it stays silent (a broadcast gets no instruction-error
status), which leaves a hole in the chain's packet that the host sees as a failed read.

Pure functions: build_fast_status (the emulator's side), split_fast_status (the driver's side, after the
sdk has received the packet), byte counts for rx timeouts; choose_fast_sync_read is the start-up probe.
"""

from __future__ import annotations

from hardware.dynamixel import protocol as p

FAST_SYNC_READ_MIN_FIRMWARE = 45  # Firmware Version(6) from which X-series servos answer 0x8A
FAST_HEADER_LEN = 8  # FF FF FD 00, ID FE, LEN_L LEN_H, INST 55
BLOCK_OVERHEAD = 4  # ERR, ID, CRC_L, CRC_H around each servo's L data bytes
INSTRUCTION_OVERHEAD = 14  # a sync read instruction without its id list (header .. length, CRC)
STATUS_OVERHEAD = 11  # one plain status packet without its data
PROBE_TRIES = 3  # fast reads at start-up before the chain counts as not supporting it
_FAST_PREFIX = p.HEADER + bytes([p.BROADCAST_ID])


def plain_sync_read_bytes(n_servos: int, length: int) -> int:
    """Bytes on the wire for one plain sync read: instruction + n status packets."""
    return INSTRUCTION_OVERHEAD + n_servos + n_servos * (STATUS_OVERHEAD + length)


def fast_sync_read_bytes(n_servos: int, length: int) -> int:
    """Bytes on the wire for one fast sync read: instruction + the one status packet."""
    return INSTRUCTION_OVERHEAD + n_servos + FAST_HEADER_LEN + n_servos * (length + BLOCK_OVERHEAD)


def fast_status_len(n_servos: int, length: int) -> int:
    """The LEN field of a fast sync read reply for n servos of `length` data bytes each."""
    return 1 + n_servos * (length + BLOCK_OVERHEAD)


def build_fast_status(blocks: list[tuple[int, int, bytes] | None], length: int) -> bytes:
    """The bytes a chain puts on the wire for blocks [(id, error byte, data)] in instruction order; None is
    a servo that stays silent (unsupported firmware, unpowered): its slot stays empty and, when it is the
    first, nobody sends the header. Later servos' CRCs run over what is on the wire, as they hear it."""
    out = bytearray()
    if blocks and blocks[0] is not None:
        ln = fast_status_len(len(blocks), length)
        out += _FAST_PREFIX + bytes([ln & 0xFF, ln >> 8, p.INST_STATUS])
    crc, done = 0, 0  # the running CRC covers out[:done]
    for b in blocks:
        if b is None:
            continue
        dxl_id, err, data = b
        out += bytes([err & 0xFF, dxl_id & 0xFF]) + bytes(data[:length]).ljust(length, b"\x00")
        crc = p.crc16(out[done:], crc)
        done = len(out)
        out += bytes([crc & 0xFF, crc >> 8])
    return bytes(out)


def split_fast_status(
    pkt, ids: list[int], length: int, crc_checked: bool
) -> dict[int, tuple[bytes, int]]:
    """{id: (data, status error byte)} from a received fast sync read reply (never raises).

    crc_checked: the sdk verified the packet CRC (over every byte), so only the layout and ids are checked;
    otherwise (a corrupt or truncated reply) the blocks are taken up to the first whose running CRC or id
    does not match -- those before it are intact. A block with an error number (not just the alert bit)
    carries no usable data and is left out, as a plain sync read's data-less status is."""
    buf = bytes(pkt or b"")
    n, step = len(ids), length + BLOCK_OVERHEAD
    out: dict[int, tuple[bytes, int]] = {}
    if (
        len(buf) < FAST_HEADER_LEN
        or buf[:5] != _FAST_PREFIX
        or buf[7] != p.INST_STATUS
        or buf[5] | (buf[6] << 8) != fast_status_len(n, length)
    ):
        return out
    if crc_checked and len(buf) == 7 + fast_status_len(n, length):
        for k, dxl_id in enumerate(ids):
            o = FAST_HEADER_LEN + k * step
            if buf[o + 1] != dxl_id:
                return {}  # a valid packet for another id list: nothing in it is ours
            if not buf[o] & 0x7F:
                out[dxl_id] = (buf[o + 2 : o + 2 + length], buf[o])
        return out
    crc, pos = 0, 0
    for k, dxl_id in enumerate(ids):
        o = FAST_HEADER_LEN + k * step
        end = o + 2 + length  # this block's CRC follows its data
        if end + 2 > len(buf) or buf[o + 1] != dxl_id:
            break
        crc = p.crc16(buf[pos:end], crc)
        if crc != buf[end] | (buf[end + 1] << 8):
            break
        pos = end
        if not buf[o] & 0x7F:
            out[dxl_id] = (buf[o + 2 : end], buf[o])
    return out


def choose_fast_sync_read(setting, bus, group, ids: list[int], timeout_ms: float,
                          firmware: dict[int, int]) -> tuple[bool, str | None]:
    """(use fast sync read, why not) for a config setting True / False / "auto".

    Servos whose firmware (read at connect; -1 unknown) is known to predate the instruction rule it out
    without a try; otherwise up to PROBE_TRIES fast reads must give every servo's block. The reason names
    the first servo that failed it."""
    if setting is False:
        return False, None
    old = [i for i in ids if 0 <= firmware.get(i, -1) < FAST_SYNC_READ_MIN_FIRMWARE]
    if old:
        return False, f"servo {old[0]} (firmware v{firmware[old[0]]}, needs v{FAST_SYNC_READ_MIN_FIRMWARE})"
    best: dict = {}
    for _ in range(PROBE_TRIES):
        got = bus.sync_read(group, ids, timeout_ms, fast=True)
        if len(got) == len(ids):
            return True, None
        best = got if len(got) > len(best) else best
    bad = next(i for i in ids if i not in best)
    fw = firmware.get(bad, -1)
    return False, f"servo {bad} (firmware v{fw}; no valid fast reply in {PROBE_TRIES} tries)"
