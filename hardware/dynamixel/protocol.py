"""Dynamixel Protocol 2.0 wire codec: pure functions, no I/O.

Packet layout (ROBOTIS e-manual, Protocol 2.0):
    FF FF FD 00 | ID | LEN_L LEN_H | INST | params... | CRC_L CRC_H
LEN counts INST + params + CRC (instruction: params + 3; status: INST 0x55, ERR, params -> params + 4).
Byte stuffing: wherever FF FF FD occurs from INST onwards an extra FD is inserted (LEN counts it) so the
header cannot appear inside a packet. CRC-16 (poly 0x8005, init 0, MSB-first, no reflection, no final
xor) covers header .. last (stuffed) parameter.

This module is the one source for the protocol constants (instructions, error codes, control-table
addresses, unit scales) used by the leader driver, the emulator, the doctor and the tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from fastcrc.crc16 import umts as _umts

from hardware.small_vec import all_finite

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 252
MAX_BODY_LEN = 1024  # bytes: longest LEN we accept (dynamixel-sdk's RXPACKET_MAX_LEN)

# -- instructions -------------------------------------------------------------------------------------
INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REG_WRITE = 0x04
INST_ACTION = 0x05
INST_FACTORY_RESET = 0x06
INST_REBOOT = 0x08
INST_CLEAR = 0x10
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_FAST_SYNC_READ = 0x8A
INST_BULK_READ = 0x92
INST_BULK_WRITE = 0x93
INST_FAST_BULK_READ = 0x9A
KNOWN_INSTRUCTIONS = frozenset(
    {
        INST_PING,
        INST_READ,
        INST_WRITE,
        INST_REG_WRITE,
        INST_ACTION,
        INST_FACTORY_RESET,
        INST_REBOOT,
        INST_CLEAR,
        INST_STATUS,
        INST_SYNC_READ,
        INST_SYNC_WRITE,
        INST_FAST_SYNC_READ,
        INST_BULK_READ,
        INST_BULK_WRITE,
        INST_FAST_BULK_READ,
    }
)

# -- status error byte (bits 0..6 an error number, bit 7 the hardware alert flag) ----------------------
ERR_NONE = 0
ERR_RESULT_FAIL = 1
ERR_INSTRUCTION = 2
ERR_CRC = 3
ERR_DATA_RANGE = 4
ERR_DATA_LENGTH = 5
ERR_DATA_LIMIT = 6
ERR_ACCESS = 7
ERR_ALERT_BIT = 0x80
ERROR_NAMES = {
    ERR_RESULT_FAIL: "result fail",
    ERR_INSTRUCTION: "instruction error",
    ERR_CRC: "CRC error",
    ERR_DATA_RANGE: "data range error",
    ERR_DATA_LENGTH: "data length error",
    ERR_DATA_LIMIT: "data limit error",
    ERR_ACCESS: "access error",
}

# -- control table: (address, size in bytes); same addresses on XL330 / XC330 / XM430 ---------------
ADDR_MODEL_NUMBER = (0, 2)
ADDR_MODEL_INFORMATION = (2, 4)
ADDR_FIRMWARE_VERSION = (6, 1)
ADDR_ID = (7, 1)
ADDR_BAUD_RATE = (8, 1)
ADDR_RETURN_DELAY_TIME = (9, 1)  # 2 us per unit, factory 250 (= 500 us)
ADDR_DRIVE_MODE = (10, 1)
ADDR_OPERATING_MODE = (11, 1)
ADDR_PROTOCOL_TYPE = (13, 1)
ADDR_HOMING_OFFSET = (20, 4)
ADDR_TEMPERATURE_LIMIT = (31, 1)
ADDR_CURRENT_LIMIT = (38, 2)
ADDR_VELOCITY_LIMIT = (44, 4)
ADDR_MAX_POSITION_LIMIT = (48, 4)
ADDR_MIN_POSITION_LIMIT = (52, 4)
EEPROM_END = 64  # addresses below this are EEPROM: writable only with torque off
ADDR_TORQUE_ENABLE = (64, 1)
ADDR_LED = (65, 1)
ADDR_STATUS_RETURN_LEVEL = (68, 1)
ADDR_HARDWARE_ERROR_STATUS = (70, 1)
ADDR_BUS_WATCHDOG = (98, 1)
ADDR_GOAL_PWM = (100, 2)
ADDR_GOAL_CURRENT = (102, 2)  # signed
ADDR_GOAL_VELOCITY = (104, 4)
ADDR_GOAL_POSITION = (116, 4)
ADDR_REALTIME_TICK = (120, 2)
ADDR_MOVING = (122, 1)
ADDR_PRESENT_PWM = (124, 2)
ADDR_PRESENT_CURRENT = (126, 2)  # signed
ADDR_PRESENT_VELOCITY = (128, 4)  # signed, 0.229 rev/min per unit
ADDR_PRESENT_POSITION = (132, 4)  # signed, 4096 per rev
ADDR_PRESENT_INPUT_VOLTAGE = (144, 2)
ADDR_PRESENT_TEMPERATURE = (146, 1)
CONTROL_TABLE_SIZE = 148  # bytes the emulator models (up to present temperature)

# Per-tick feedback block: present current, velocity, position are contiguous (126..135).
FEEDBACK_START = ADDR_PRESENT_CURRENT[0]
FEEDBACK_LEN = 10
FEEDBACK_NO_CURRENT_START = ADDR_PRESENT_VELOCITY[0]
FEEDBACK_NO_CURRENT_LEN = 8

OP_MODE_CURRENT = 0
OP_MODE_VELOCITY = 1
OP_MODE_POSITION = 3
OP_MODE_EXTENDED_POSITION = 4
OP_MODE_CURRENT_BASED_POSITION = 5
OP_MODE_PWM = 16
OP_MODE_NAMES = {
    0: "current",
    1: "velocity",
    3: "position",
    4: "extended position",
    5: "current-based position",
    16: "PWM",
}

BAUD_CODES = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000}
RETURN_DELAY_UNIT_S = 2e-6

HW_ERROR_BITS = {
    0: "input voltage",
    2: "overheating",
    3: "motor encoder",
    4: "electrical shock",
    5: "overload",
}

# -- units --------------------------------------------------------------------------------------------
TICKS_PER_REV = 4096
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
VELOCITY_UNIT_RPM = 0.229
RAD_S_PER_VELOCITY_UNIT = VELOCITY_UNIT_RPM * 2.0 * math.pi / 60.0


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x8005) if c & 0x8000 else (c << 1)
        table.append(c & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16/BUYPASS (= CRC-16/UMTS: poly 0x8005, init 0, MSB-first) over data, continuing from crc.
    fastcrc's compiled code: this runs on every packet of the 500 Hz loop, where the per-byte (or
    two-byte-table) Python loop was ~5 % of the teleop tick (issue #53). _CRC_TABLE stays as the
    reference the tests check it against."""
    return _umts(data, crc)


def stuff(body: bytes | bytearray) -> bytes:
    """Insert FD after every FF FF FD in body (INST + params)."""
    if b"\xff\xff\xfd" not in body:
        return bytes(body)  # the common case, without the per-byte loop
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes | bytearray) -> bytes:
    """Remove the FD that stuffing inserted after every FF FF FD."""
    if b"\xff\xff\xfd\xfd" not in body:
        return bytes(body)
    out = bytearray()
    i, n = 0, len(body)
    while i < n:
        b = body[i]
        out.append(b)
        if (
            b == 0xFD
            and len(out) >= 3
            and out[-3] == 0xFF
            and out[-2] == 0xFF
            and i + 1 < n
            and body[i + 1] == 0xFD
        ):
            i += 1  # skip the stuffed FD
        i += 1
    return bytes(out)


def _frame(dxl_id: int, body: bytes) -> bytes:
    s = stuff(body)
    ln = len(s) + 2
    pkt = HEADER + bytes([dxl_id & 0xFF, ln & 0xFF, (ln >> 8) & 0xFF]) + s
    c = crc16(pkt)
    return pkt + bytes([c & 0xFF, c >> 8])


def build_instruction(dxl_id: int, instruction: int, params: bytes | bytearray = b"") -> bytes:
    """A complete instruction packet (stuffed, with CRC)."""
    return _frame(dxl_id, bytes([instruction]) + bytes(params))


def build_status(dxl_id: int, error: int = 0, params: bytes | bytearray = b"") -> bytes:
    """A complete status packet (instruction 0x55, error byte, params)."""
    return _frame(dxl_id, bytes([INST_STATUS, error & 0xFF]) + bytes(params))


def le(value: int, size: int) -> bytes:
    """value as size little-endian bytes (two's complement for negatives)."""
    return int(value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")


def from_le(data: bytes | bytearray, signed: bool = False) -> int:
    return int.from_bytes(bytes(data), "little", signed=signed)


def read_params(address: int, size: int) -> bytes:
    return le(address, 2) + le(size, 2)


def sync_read_params(address: int, size: int, ids: list[int]) -> bytes:
    return le(address, 2) + le(size, 2) + bytes(ids)


def sync_write_params(address: int, size: int, data: dict[int, bytes]) -> bytes:
    out = bytearray(le(address, 2) + le(size, 2))
    for i, d in data.items():
        out.append(i)
        out += d
    return bytes(out)


@dataclass(frozen=True)
class Packet:
    """A decoded packet. instruction 0x55 means status: error is its error byte and params follow it."""

    id: int
    instruction: int
    params: bytes
    error: int = 0

    @property
    def is_status(self) -> bool:
        return self.instruction == INST_STATUS


class PacketParser:
    """Incremental stream parser: feed() bytes, get complete packets; never raises on garbage.

    Counters: garbage_bytes (bytes outside any packet), bad_crc, bad_length, unknown_instruction,
    stale_partials (incomplete packets given up by discard_partial()), packets (good ones).
    """

    def __init__(self, max_body_len: int = MAX_BODY_LEN):
        self.max_body_len = max_body_len
        self.buf = bytearray()
        self.packets = self.garbage_bytes = self.bad_crc = self.bad_length = 0
        self.unknown_instruction = self.stale_partials = 0

    @property
    def errors(self) -> int:
        return self.bad_crc + self.bad_length + self.unknown_instruction + self.stale_partials

    def _drop(self, n: int) -> None:
        del self.buf[:n]

    def feed(self, data: bytes | bytearray) -> list[Packet]:
        self.buf += data
        out: list[Packet] = []
        while True:
            i = self.buf.find(HEADER)
            if i < 0:
                keep = next((k for k in (3, 2, 1) if self.buf.endswith(HEADER[:k])), 0)
                self.garbage_bytes += len(self.buf) - keep
                self._drop(len(self.buf) - keep)
                return out
            if i:
                self.garbage_bytes += i
                self._drop(i)
            if len(self.buf) < 7:
                return out
            ln = self.buf[5] | (self.buf[6] << 8)
            if ln < 3 or ln > self.max_body_len:
                self.bad_length += 1
                self._drop(1)
                continue
            total = 7 + ln
            if len(self.buf) < total:
                return out
            crc = self.buf[total - 2] | (self.buf[total - 1] << 8)
            if crc16(self.buf[: total - 2]) != crc:
                self.bad_crc += 1
                self._drop(1)  # the header may have been false: resync one byte on
                continue
            body = unstuff(self.buf[7 : total - 2])
            dxl_id = self.buf[4]
            self._drop(total)
            inst = body[0]
            if inst not in KNOWN_INSTRUCTIONS:
                self.unknown_instruction += 1
                continue
            if inst == INST_STATUS:
                if len(body) < 2:
                    self.bad_length += 1
                    continue
                out.append(Packet(dxl_id, inst, bytes(body[2:]), body[1]))
            else:
                out.append(Packet(dxl_id, inst, bytes(body[1:])))
            self.packets += 1

    def discard_partial(self) -> None:
        """Give up an incomplete packet (a receiver timeout): drop one byte and resync on what follows."""
        if self.buf:
            self.stale_partials += 1
            rest = bytes(self.buf[1:])
            self.buf.clear()
            self.feed(rest)


def parse_packets(data: bytes | bytearray) -> list[Packet]:
    """All complete packets in data (convenience for tests and one-shot decoding)."""
    return PacketParser().feed(data)


# -- unit conversions (numpy-friendly) -------------------------------------------------------------
def to_signed(value, size: int):
    """Two's-complement view of an unsigned size-byte value (dynamixel-sdk getData returns unsigned)."""
    v = np.asarray(value, dtype=np.int64)
    bits = 8 * size
    v = v & ((1 << bits) - 1)
    out = np.where(v >= (1 << (bits - 1)), v - (1 << bits), v)
    return int(out) if np.ndim(out) == 0 else out


def to_unsigned(value, size: int):
    v = np.asarray(value, dtype=np.int64) & ((1 << (8 * size)) - 1)
    return int(v) if np.ndim(v) == 0 else v


def ticks_to_rad(ticks):
    """Position ticks (4096 per rev) -> rad."""
    return np.asarray(ticks, dtype=float) * RAD_PER_TICK


def rad_to_ticks(rad):
    """rad -> position ticks (rounded)."""
    return np.rint(np.asarray(rad, dtype=float) / RAD_PER_TICK).astype(np.int64)


def velocity_units_to_rad_s(units):
    """Present velocity units (0.229 rev/min) -> rad/s."""
    return np.asarray(units, dtype=float) * RAD_S_PER_VELOCITY_UNIT


def rad_s_to_velocity_units(rad_s):
    return np.rint(np.asarray(rad_s, dtype=float) / RAD_S_PER_VELOCITY_UNIT).astype(np.int64)


def current_units_to_amps(units, amps_per_unit):
    """Present/goal current units -> A (amps_per_unit: 0.001 on XL330/XC330, 0.00269 on XM430)."""
    return np.asarray(units, dtype=float) * np.asarray(amps_per_unit, dtype=float)


def amps_to_current_units(amps, amps_per_unit, limit_units=None):
    """A -> goal current units, rounded, clipped to +-limit_units (the servo's Current Limit(38))."""
    u = np.asarray(amps, dtype=float) / np.asarray(amps_per_unit, dtype=float)
    if u.ndim != 1 or not all_finite(u):  # the usual 1-D finite vector skips the where (500 Hz)
        u = np.where(np.isfinite(u), u, 0.0)
    if limit_units is not None:
        lim = np.asarray(limit_units, dtype=float)
        u = np.minimum(np.maximum(u, -lim), lim)
    return np.rint(u).astype(np.int64)


def describe_error(error: int) -> str:
    """Human text for a status error byte."""
    parts = []
    if error & 0x7F:
        parts.append(ERROR_NAMES.get(error & 0x7F, f"error {error & 0x7F}"))
    if error & ERR_ALERT_BIT:
        parts.append("hardware alert (read Hardware Error Status(70))")
    return ", ".join(parts) or "ok"
