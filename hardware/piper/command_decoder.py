"""The arm side of the Piper's command frames (emulators): validate (DLC, known id, MIT crc), count what is
rejected, decode into plain numbers (hardware/piper/protocol.py's ids, scales and layouts). Never raises."""

from __future__ import annotations

from hardware.can_bus import RejectCounters, frame_ok
from hardware.piper.protocol import (
    _S_GRIP_CMD,
    _S_MODE,
    COMMAND_IDS,
    DISABLE_CODE,
    ENABLE_CODE,
    FRAME_DLC,
    ID_ENABLE,
    ID_GRIPPER_CMD,
    ID_JOINT_TARGET,
    ID_MIT,
    ID_MODE,
    ID_PARAM_QUERY,
    MILLI,
    UM_PER_M,
    decode_joint_pair,
    decode_mit,
    mit_crc_ok,
)


def decode_mode(d: bytes) -> tuple[int, int, int, int, int, int]:
    """(ctrl_mode, move_mode, speed_pct, mit_mode, residence_s, install)."""
    return _S_MODE.unpack(d)


def decode_gripper_cmd(d: bytes) -> tuple[float, float, int, int]:
    """(stroke m, effort N*m, code, set_zero)."""
    s, e, code, zero = _S_GRIP_CMD.unpack(d)
    return s / UM_PER_M, e * MILLI, code, zero


def decode_enable(d: bytes) -> tuple[int, bool | None]:
    """(motor 1-6 or 7=all, True enable / False disable / None unknown code)."""
    motor, code = d[0], d[1]
    return motor, (True if code == ENABLE_CODE else False if code == DISABLE_CODE else None)


class PiperCommandDecoder:
    """Arm side (emulators): validates command frames (DLC, id, MIT crc) and decodes them.

    decode() returns (kind, payload) with kind in "mode", "joint", "gripper", "mit", "enable", "query",
    "firmware", or None for a rejected frame (counted)."""

    def __init__(self):
        self.counters = RejectCounters()

    def decode(self, arb_id: int, data, is_ext: bool = False, is_special: bool = False):
        if arb_id in _TARGET_INDEX and not (is_ext or is_special) and len(data) == FRAME_DLC:
            # the frames of every command tick (3 of ~5): validated and decoded here in one go
            self.counters.ok += 1
            return "joint", (_TARGET_INDEX[arb_id], decode_joint_pair(bytes(data)))
        if not frame_ok(self.counters, COMMAND_IDS, arb_id, data, is_ext, is_special):
            return None
        d = bytes(data)
        if arb_id in _MIT_INDEX:
            if not mit_crc_ok(d):
                self.counters.bad_crc += 1
                return None
            self.counters.ok += 1
            return "mit", (_MIT_INDEX[arb_id], decode_mit(d))
        self.counters.ok += 1
        if arb_id == ID_MODE:
            return "mode", decode_mode(d)
        if arb_id == ID_GRIPPER_CMD:
            return "gripper", decode_gripper_cmd(d)
        if arb_id == ID_ENABLE:
            return "enable", decode_enable(d)
        if arb_id == ID_PARAM_QUERY:
            return "query", (d[0], d[1])
        return "firmware", d


_MIT_INDEX = {i: j for j, i in enumerate(ID_MIT)}
_TARGET_INDEX = {i: j for j, i in enumerate(ID_JOINT_TARGET)}
