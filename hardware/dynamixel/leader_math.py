"""The Dynamixel leader's math: pure functions on numbers and arrays (leader.py, the driver, is the shell).

Decoding a servo's feedback block, resolving the power-on turn (wrap_to_offset), unwrapping tick deltas,
servo angle -> joint angle, joint torque [N*m] -> goal-current units, the trigger's angle -> 0..1.
"""

from __future__ import annotations

import functools
import math
import struct

import numpy as np

from hardware.dynamixel import protocol as p
from hardware.dynamixel.fast_sync import _FAST_PREFIX, fast_status_len

TWO_PI = 2.0 * math.pi
HALF_TURN_TICKS = p.TICKS_PER_REV // 2
_TICK_MASK = p.TICKS_PER_REV - 1  # TICKS_PER_REV (4096) is a power of two: x & mask == x % TICKS_PER_REV


def decode_feedback(data: bytes, with_current: bool) -> tuple[int, int, int]:
    """(current units, velocity units, position ticks), signed, from one servo's sync-read block."""
    cur = p.from_le(data[0:2], True) if with_current else 0
    k = 2 if with_current else 0
    return cur, p.from_le(data[k : k + 4], True), p.from_le(data[k + 4 : k + 8], True)


@functools.lru_cache(maxsize=8)
def _blocks_struct(with_current: bool, m: int) -> struct.Struct:
    """decode_feedback's fields of m servo blocks back to back, flat: (current,) velocity, position each."""
    return struct.Struct("<" + ("hii" if with_current else "ii") * m)


class FastReplyDecoder:
    """A whole Fast Sync Read reply whose CRC checked (sync_io.fast_sync_read_reply) -> its fields in ONE
    struct unpack over the reply's bytes: no per-servo slices, dict or joined bytes (the 500 Hz read).

    fields(buf) is the tuple (prefix, LEN, INST, then per servo: error, id, (current,) velocity, position,
    CRC), or None unless the reply is exactly the usual one -- the header, LEN and instruction of this id
    list, every block's id in order and every error byte 0. Anything else (an alert bit, an error number, a
    reply of another length or for other ids) goes the general way (fast_sync.split_fast_status), so the
    values out are split_fast_status + decode_feedback's, and what that rejects is rejected here too."""

    def __init__(self, ids: list[int], with_current: bool):
        m, length = len(ids), p.FEEDBACK_LEN if with_current else p.FEEDBACK_NO_CURRENT_LEN
        self.width = 6 if with_current else 5  # fields per servo block
        self.struct = struct.Struct("<5sHB" + ("BBhiiH" if with_current else "BBiiH") * m)
        self.head = (bytes(_FAST_PREFIX), fast_status_len(m, length), p.INST_STATUS)
        self.ids, self.zeros = tuple(int(i) for i in ids), (0,) * m
        # where each field's run starts in the tuple (a slice [start::width] reads it for every servo)
        self.cur, self.vel, self.pos = (5, 6, 7) if with_current else (None, 5, 6)

    def fields(self, buf) -> tuple | None:
        if len(buf) != self.struct.size:
            return None
        v, w = self.struct.unpack_from(buf), self.width
        if v[:3] != self.head or v[4::w] != self.ids or v[3::w] != self.zeros:
            return None
        return v

    def runs(self, buf) -> tuple | None:
        """fields(buf) as the leader's tick takes it: (position ticks, velocity units, current units or
        None), each a tuple in id order; None where fields() gives None (its checks written out)."""
        if len(buf) != self.struct.size:
            return None
        v, w = self.struct.unpack_from(buf), self.width
        if v[:3] != self.head or v[4::w] != self.ids or v[3::w] != self.zeros:
            return None
        return v[self.pos::w], v[self.vel::w], None if self.cur is None else v[self.cur::w]


def wrap_to_offset(q_servo_rad: np.ndarray, offset_rad: np.ndarray) -> np.ndarray:
    """q_servo + 2*pi*k with k chosen so the result is closest to offset (resolves power-on turns)."""
    q, off = np.asarray(q_servo_rad, float), np.asarray(offset_rad, float)
    return q + TWO_PI * np.round((off - q) / TWO_PI)


def wrapped_tick_delta(ticks_now: np.ndarray, ticks_prev: np.ndarray) -> np.ndarray:
    """Tick difference wrapped to [-2048, 2048): a servo cannot turn half a revolution in one tick."""
    d = np.asarray(ticks_now, np.int64) - np.asarray(ticks_prev, np.int64)
    return (d + HALF_TURN_TICKS) % p.TICKS_PER_REV - HALF_TURN_TICKS


def servo_to_joint(q_servo_rad, signs, offsets_rad) -> np.ndarray:
    return np.asarray(signs, float) * (np.asarray(q_servo_rad, float) - np.asarray(offsets_rad, float))


def torque_to_current_units(tau_nm, signs, k_nm_per_a, amps_per_unit, limit_units) -> np.ndarray:
    """Joint torques [N*m] -> servo goal-current units (sign applied, clipped to the Current Limit)."""
    amps = np.asarray(signs, float) * np.asarray(tau_nm, float) / np.asarray(k_nm_per_a, float)
    return p.amps_to_current_units(amps, amps_per_unit, limit_units)


def torque_to_current_ints(tau_nm: list[float], signs: list[float], k_nm_per_a: list[float],
                           amps_per_unit: list[float], limit_units: list[float]) -> list[int]:
    """torque_to_current_units on plain floats, bit for bit (the 500 Hz path): sign * tau / K / amps per
    unit, a non-finite value 0, clipped to +-limit (numpy's maximum / minimum: a NaN limit wins), rounded
    half to even (np.rint; Python's round of a float does the same)."""
    # a value strictly inside +-limit is finite and unclipped (what numpy's maximum / minimum give it too);
    # any other (NaN, inf, at or past the limit) goes the whole way. u is a float (a true division):
    # float.__round__ is round()'s own method, called without round()'s lookup of it. The lengths checked
    # apart: zip's strict= keyword costs more than the check
    if not len(tau_nm) == len(signs) == len(k_nm_per_a) == len(amps_per_unit) == len(limit_units):
        raise ValueError(f"torque_to_current_ints: {len(tau_nm)} torques for {len(signs)} joints")
    return [float.__round__(u) if -lim < (u := s * t / k / a) < lim else _units_clipped(u, lim)
            for t, s, k, a, lim in zip(tau_nm, signs, k_nm_per_a, amps_per_unit, limit_units)]


def _units_clipped(u: float, lim: float) -> int:
    """torque_to_current_ints for one value u not strictly inside +-lim: a non-finite u 0, then clipped as
    numpy's maximum / minimum do (a NaN limit wins), rounded half to even."""
    u = u if math.isfinite(u) else 0.0
    lo = -lim
    u = u if (u > lo or u != u) else lo
    u = u if (u < lim or u != u) else lim
    return round(u)


def trigger_fraction(q_servo_rad: float, open_rad: float, closed_rad: float) -> float:
    """Trigger servo angle -> 0 (open) .. 1 (closed), clipped."""
    span = closed_rad - open_rad
    if span == 0 or not math.isfinite(q_servo_rad):
        return float("nan")
    return min(max((float(q_servo_rad) - open_rad) / span, 0.0), 1.0)
