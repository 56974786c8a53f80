"""What puts a teleop pair on hold: the typed reasons (PairHold, hardware.reasons) and the checks of each
sample behind them -- freshness, completeness (no joint flagged stale) and motor errors -- as pure functions
of a JointState (teleop/pair.py runs them every tick on both arms' samples)."""

from __future__ import annotations

import logging
import math
from enum import Enum

import numpy as np

from hardware.reasons import messages
from hardware.small_vec import bits_or
from hardware.types import (
    STATUS_COMM_LOST,
    STATUS_DRIVER_ERROR,
    STATUS_MOTOR_ERROR,
    STATUS_OVERCURRENT,
    STATUS_OVERTEMP,
    STATUS_STALE,
    JointState,
)

_STALE_BITS = int(STATUS_STALE | STATUS_COMM_LOST)
_ERROR_BITS = int(STATUS_MOTOR_ERROR)
_ERROR_NAMES = ((STATUS_OVERCURRENT, "over-current"), (STATUS_OVERTEMP, "over-temperature"),
                (STATUS_DRIVER_ERROR, "driver/encoder error"))


class PairHold(Enum):
    """Why a pair made its arms safe (hardware.reasons)."""

    DATA_STALE = "data stale"  # detail: who ("leader" / "follower"), age_ms
    MOTOR_ERROR = "motor error"  # detail: who, what ("j2 over-current")
    NO_DATA_AT_START = "no data at start"
    START_MISMATCH = "start refused: leader/follower mismatch"
    LOOP_FAULT = "teleop fault"
    LOOP_STOPPED = "teleop stopped"
    LOOP_NOT_ANSWERING = "teleop stop (loop thread not answering)"
    LOOP_GAP = "loop gap"  # detail: gap_ms (the app itself did not run: SIGSTOP, a sleeping host)


messages({
    PairHold.DATA_STALE: "{who} data stale ({age_ms:.0f} ms old)",
    PairHold.LOOP_GAP: "the loop did not run for {gap_ms:.0f} ms (the app was stopped); re-coupling "
                       "through the soft start",
    PairHold.MOTOR_ERROR: "{who} motor error: {what}",
    PairHold.NO_DATA_AT_START: "no data at start",
    PairHold.START_MISMATCH: "start refused: leader/follower mismatch",
    PairHold.LOOP_FAULT: "teleop fault",
    PairHold.LOOP_STOPPED: "teleop stopped",
    PairHold.LOOP_NOT_ANSWERING: "teleop stop (loop thread not answering)",
})


def _fresh(st: JointState, now: float, max_age: float, since: float = -math.inf) -> bool:
    """Finite, at most max_age [s] old, and taken at or after `since` [s] (a start wants a new sample)."""
    return bool(np.isfinite(st.q).all()) and math.isfinite(st.t) and now - st.t <= max_age and st.t >= since


def status_bits(st: JointState) -> int:
    """Every status bit any joint of the sample has (one reduction; the per-tick checks test bits of it)."""
    status = getattr(st, "status", None)
    if status is None:
        return 0
    if type(status) is np.ndarray and status.ndim == 1 and status.dtype.kind == "u":
        return bits_or(status)  # the drivers' uint32 vector: no numpy reduction on the hot path
    return int(np.bitwise_or.reduce(np.asarray(status, dtype=np.uint32)))


def motor_errors(st: JointState) -> str:
    """The motor errors a sample reports ("j2 over-current, j3 over-temperature"), "" when none."""
    if not status_bits(st) & _ERROR_BITS:
        return ""
    return ", ".join(f"j{j + 1} {name}" for j, s in enumerate(np.asarray(st.status).tolist())
                     for bit, name in _ERROR_NAMES if s & bit)


def _complete(st: JointState) -> bool:
    """A sample in which every joint is new: drivers re-stamp a partial/failed read with the read time and
    flag the joints that kept old values (STATUS_STALE / STATUS_COMM_LOST), so age alone cannot tell."""
    return not status_bits(st) & _STALE_BITS


def device_notes(devices: dict, jumps: dict, turns: dict) -> list[tuple[str, int]]:
    """(text, log level) for each count a device moved since the last call -- implausible jumps held
    (safety.jumps_rejected), readings put back on their turn (turns_unwrapped) -- the counts seen kept in
    jumps / turns ({who: count}). devices: {who: Device}. [] on the usual tick (four numbers compared)."""
    out = []
    for who, dev in devices.items():
        n = dev.safety.jumps_rejected
        if n != jumps[who]:
            jumps[who] = n
            out.append((f"{who} encoder jump rejected (implausible in one sample): previous value held",
                        logging.WARNING))
        n = getattr(dev, "turns_unwrapped", 0)
        if n != turns[who]:
            turns[who] = n
            out.append((f"{who} reading a whole turn off: put back on the joint's turn (hardware/wrap.py)",
                        logging.INFO))
    return out
