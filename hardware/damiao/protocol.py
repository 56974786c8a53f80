"""Damiao DM43xx motors in MIT mode over classic CAN: every constant of the wire in one place, pure codecs.

Source: shared/reference/hardware-protocols.md (Damiao section). MIT command on the slave id, exactly one
feedback frame per command on the master id (convention slave + 0x10), special frames (enable, disable,
save zero, clear error) on the slave id, registers through id 0x7FF with the reply on the master id.
Position/velocity/torque ranges (PMAX/VMAX/TMAX) are per motor: read registers 21-23 at start-up and pass
them in as MotorRanges; MODEL_RANGES holds only the datasheet defaults.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from hardware.can_bus import RejectCounters, float_to_uint, uint_to_float
from hardware.types import (
    STATUS_COMM_LOST,
    STATUS_DRIVER_ERROR,
    STATUS_ENABLED,
    STATUS_OVERCURRENT,
    STATUS_OVERTEMP,
    STATUS_STALL,
    STATUS_UNDERVOLTAGE,
)

FRAME_DLC = 8
MASTER_ID_OFFSET = 0x10  # default feedback id = slave id + this
ID_POS_VEL_BASE, ID_VEL_BASE, ID_POS_FORCE_BASE = 0x100, 0x200, 0x300  # other control modes (not used here)
ID_REGISTER = 0x7FF

# MIT gain ranges are fixed by the firmware; position/velocity/torque ranges come from registers 21-23
KP_MIN, KP_MAX = 0.0, 500.0  # N*m/rad, 12 bit
KD_MIN, KD_MAX = 0.0, 5.0  # N*m*s/rad, 12 bit
P_BITS, V_BITS, KP_BITS, KD_BITS, T_BITS = 16, 12, 12, 12, 12

# special frames: FF x7 then the code
CODE_ENABLE, CODE_DISABLE, CODE_SAVE_ZERO, CODE_CLEAR_ERROR = 0xFC, 0xFD, 0xFE, 0xFB
SPECIAL_PREFIX = b"\xff" * 7

# registers
REG_READ, REG_WRITE, REG_SAVE = 0x33, 0x55, 0xAA
RID_MASTER_ID, RID_SLAVE_ID, RID_TIMEOUT, RID_CTRL_MODE = 7, 8, 9, 10
RID_PMAX, RID_VMAX, RID_TMAX, RID_CAN_BAUD = 21, 22, 23, 35
FLOAT_RIDS = frozenset((RID_PMAX, RID_VMAX, RID_TMAX))  # float32 registers; the others are uint32
TIMEOUT_UNIT_S = 50e-6  # register 9 counts 50 us
CTRL_MODE_MIT, CTRL_MODE_POS_VEL, CTRL_MODE_VEL, CTRL_MODE_POS_FORCE = 1, 2, 3, 4

# feedback ERR nibble
ERR_DISABLED, ERR_ENABLED = 0x0, 0x1
ERR_OVERVOLTAGE, ERR_UNDERVOLTAGE, ERR_OVERCURRENT = 0x8, 0x9, 0xA
ERR_MOS_OVERTEMP, ERR_COIL_OVERTEMP, ERR_COMM_LOST, ERR_OVERLOAD = 0xB, 0xC, 0xD, 0xE
ERR_FLAGS = {
    ERR_DISABLED: 0, ERR_ENABLED: STATUS_ENABLED, ERR_OVERVOLTAGE: STATUS_DRIVER_ERROR,
    ERR_UNDERVOLTAGE: STATUS_UNDERVOLTAGE, ERR_OVERCURRENT: STATUS_OVERCURRENT,
    ERR_MOS_OVERTEMP: STATUS_OVERTEMP,
    ERR_COIL_OVERTEMP: STATUS_OVERTEMP, ERR_COMM_LOST: STATUS_COMM_LOST, ERR_OVERLOAD: STATUS_STALL,
}
ERR_NAMES = {
    ERR_DISABLED: "disabled", ERR_ENABLED: "enabled", ERR_OVERVOLTAGE: "overvoltage",
    ERR_UNDERVOLTAGE: "undervoltage", ERR_OVERCURRENT: "overcurrent", ERR_MOS_OVERTEMP: "MOS overtemperature",
    ERR_COIL_OVERTEMP: "coil overtemperature", ERR_COMM_LOST: "communication lost", ERR_OVERLOAD: "overload",
}


@dataclass(frozen=True)
class MotorRanges:
    """PMAX [rad], VMAX [rad/s], TMAX [N*m]: the symmetric ranges the MIT codec maps onto its bits."""

    pmax: float
    vmax: float
    tmax: float


def reported_position(q: float, pmax: float) -> float:
    """The position [rad] a motor at multi-turn position q [rad] reports: rolled over into the 16-bit field's
    [-PMAX, PMAX), a period of 2 * PMAX (the follower unwraps it: DamiaoFollower.wrap_period_rad)."""
    return (q + pmax) % (2.0 * pmax) - pmax


@dataclass(frozen=True)
class MotorModel:
    ranges: MotorRanges  # datasheet defaults (registers 21-23 win)
    torque_constant: float  # N*m/A, output side
    gear_ratio: float
    tau_rated: float  # N*m
    tau_peak: float  # N*m


MODELS = {
    "DM4310": MotorModel(MotorRanges(12.5, 30.0, 10.0), 0.945, 10.0, 3.0, 7.0),
    "DM4340": MotorModel(MotorRanges(12.5, 8.0, 28.0), 4.074, 40.0, 9.0, 27.0),
}

_S_REG_HDR = struct.Struct("<HBB")
_S_REG_F = struct.Struct("<HBBf")
_S_REG_U = struct.Struct("<HBBI")


def motor_model(name: str) -> MotorModel:
    """Look up a model; KeyError names the known ones (the config layer turns it into a ConfigError)."""
    try:
        return MODELS[name.upper()]
    except KeyError:
        raise KeyError(f"unknown Damiao motor model {name!r}; known: {', '.join(sorted(MODELS))}") from None


# ---- MIT command -----------------------------------------------------------------------------------------
def encode_mit(q: float, v: float, kp: float, kd: float, tau: float, r: MotorRanges) -> bytes:
    """q [rad], v [rad/s], kp, kd, tau [N*m] -> 8 bytes (each value clamped into its range first)."""
    p = float_to_uint(q, -r.pmax, r.pmax, P_BITS)
    vv = float_to_uint(v, -r.vmax, r.vmax, V_BITS)
    kpu = float_to_uint(kp, KP_MIN, KP_MAX, KP_BITS)
    kdu = float_to_uint(kd, KD_MIN, KD_MAX, KD_BITS)
    t = float_to_uint(tau, -r.tmax, r.tmax, T_BITS)
    return bytes((p >> 8, p & 0xFF, vv >> 4, ((vv & 0xF) << 4) | (kpu >> 8), kpu & 0xFF, kdu >> 4,
                  ((kdu & 0xF) << 4) | (t >> 8), t & 0xFF))


def decode_mit(d: bytes, r: MotorRanges) -> tuple[float, float, float, float, float]:
    """8 bytes -> (q, v, kp, kd, tau) (emulator side)."""
    p = (d[0] << 8) | d[1]
    vv = (d[2] << 4) | (d[3] >> 4)
    kpu = ((d[3] & 0xF) << 8) | d[4]
    kdu = (d[5] << 4) | (d[6] >> 4)
    t = ((d[6] & 0xF) << 8) | d[7]
    return (uint_to_float(p, -r.pmax, r.pmax, P_BITS), uint_to_float(vv, -r.vmax, r.vmax, V_BITS),
            uint_to_float(kpu, KP_MIN, KP_MAX, KP_BITS), uint_to_float(kdu, KD_MIN, KD_MAX, KD_BITS),
            uint_to_float(t, -r.tmax, r.tmax, T_BITS))


# ---- feedback --------------------------------------------------------------------------------------------
def encode_feedback(slave_id: int, err: int, q: float, v: float, tau: float, t_mos_c: float, t_rotor_c: float,
                    r: MotorRanges) -> bytes:
    p = float_to_uint(q, -r.pmax, r.pmax, P_BITS)
    vv = float_to_uint(v, -r.vmax, r.vmax, V_BITS)
    t = float_to_uint(tau, -r.tmax, r.tmax, T_BITS)
    return bytes(((err & 0xF) << 4 | (slave_id & 0xF), p >> 8, p & 0xFF, vv >> 4,
                  ((vv & 0xF) << 4) | (t >> 8), t & 0xFF,
                  max(0, min(255, int(t_mos_c))), max(0, min(255, int(t_rotor_c)))))


def decode_feedback(d: bytes, r: MotorRanges) -> tuple[int, int, float, float, float, int, int]:
    """8 bytes -> (id low nibble, ERR, q rad, v rad/s, tau N*m, MOS temp degC, rotor temp degC)."""
    p = (d[1] << 8) | d[2]
    vv = (d[3] << 4) | (d[4] >> 4)
    t = ((d[4] & 0xF) << 8) | d[5]
    return (d[0] & 0xF, d[0] >> 4, uint_to_float(p, -r.pmax, r.pmax, P_BITS),
            uint_to_float(vv, -r.vmax, r.vmax, V_BITS), uint_to_float(t, -r.tmax, r.tmax, T_BITS), d[6], d[7])


def err_flags(err: int) -> int:
    """ERR nibble -> hardware.types STATUS_* flags (unknown codes -> driver error)."""
    return ERR_FLAGS.get(err, STATUS_DRIVER_ERROR)


# ---- special frames --------------------------------------------------------------------------------------
def special_frame(code: int) -> bytes:
    return SPECIAL_PREFIX + bytes((code,))


def special_code(d: bytes) -> int | None:
    """The code of a special frame (FC/FD/FE/FB), None when the frame is not one."""
    if len(d) == FRAME_DLC and bytes(d[:7]) == SPECIAL_PREFIX and d[7] in (CODE_ENABLE, CODE_DISABLE,
                                                                         CODE_SAVE_ZERO, CODE_CLEAR_ERROR):
        return d[7]
    return None


# ---- registers (id 0x7FF) --------------------------------------------------------------------------------
def encode_reg_read(slave_id: int, rid: int) -> bytes:
    return _S_REG_HDR.pack(slave_id, REG_READ, rid) + b"\x00" * 4


def encode_reg_write(slave_id: int, rid: int, value: float) -> bytes:
    if rid in FLOAT_RIDS:
        return _S_REG_F.pack(slave_id, REG_WRITE, rid, float(value))
    return _S_REG_U.pack(slave_id, REG_WRITE, rid, int(value) & 0xFFFFFFFF)


def encode_reg_save(slave_id: int) -> bytes:
    return _S_REG_HDR.pack(slave_id, REG_SAVE, 0) + b"\x00" * 4


def encode_reg_reply(slave_id: int, op: int, rid: int, value: float) -> bytes:
    """Motor -> host reply on the master id: [idL, idH, op, rid, value LE] (op 0x33 read / 0x55 write)."""
    if rid in FLOAT_RIDS:
        return _S_REG_F.pack(slave_id, op, rid, float(value))
    return _S_REG_U.pack(slave_id, op, rid, int(value) & 0xFFFFFFFF)


def decode_reg_request(d: bytes) -> tuple[int, int, int, float | int]:
    """0x7FF frame -> (slave id, op 0x33/0x55/0xAA, rid, value for writes)."""
    sid, op, rid = _S_REG_HDR.unpack_from(d)
    if op == REG_WRITE:
        value = (_S_REG_F if rid in FLOAT_RIDS else _S_REG_U).unpack(d)[3]
        return sid, op, rid, value
    return sid, op, rid, 0


def decode_reg_reply(d: bytes, slave_id: int) -> tuple[int, float | int] | None:
    """A register reply for this slave id -> (rid, value); None when the frame is not one (e.g. feedback)."""
    sid, op, rid = _S_REG_HDR.unpack_from(d)
    if sid != slave_id or op not in (REG_READ, REG_WRITE):
        return None
    return rid, (_S_REG_F if rid in FLOAT_RIDS else _S_REG_U).unpack(d)[3]


def timeout_register(timeout_s: float) -> int:
    """Seconds -> register 9 value (units of 50 us; 0 disables the motor's own timeout)."""
    return max(0, int(round(timeout_s / TIMEOUT_UNIT_S)))


# ---- validating front end --------------------------------------------------------------------------------
class DamiaoFeedbackDecoder:
    """Host side: latest valid feedback frame and receive time [s] per motor index, keyed by master id.

    push() is the cheap per-frame call of a drain loop; it counts and rejects wrong DLC, unknown ids,
    non-data frames and feedback whose id nibble does not match the motor. Register replies are queued in
    reg_replies (slave id, rid, value) instead."""

    def __init__(self, slave_ids: list[int], master_ids: list[int]):
        self.counters = RejectCounters()
        self.index = {m: i for i, m in enumerate(master_ids)}
        self.slave_ids = list(slave_ids)
        self.latest: list[bytes | None] = [None] * len(master_ids)
        self.t_rx = [float("nan")] * len(master_ids)
        self.expect_registers = False  # set while the driver waits for register replies
        self.reg_replies: list[tuple[int, int, float | int]] = []

    def push(self, arb_id: int, data, t: float, is_ext: bool = False, is_special: bool = False) -> bool:
        c = self.counters
        if is_ext or is_special:
            c.bad_frame += 1
            return False
        i = self.index.get(arb_id)
        if i is None:
            c.unknown_id += 1
            return False
        if len(data) != FRAME_DLC:
            c.bad_dlc += 1
            return False
        sid = self.slave_ids[i]
        if self.expect_registers and data[2] in (REG_READ, REG_WRITE):
            rep = decode_reg_reply(bytes(data), sid)
            if rep is not None:
                c.ok += 1
                self.reg_replies.append((sid, rep[0], rep[1]))
                return True
        if data[0] & 0xF != sid & 0xF:
            c.bad_frame += 1
            return False
        c.ok += 1
        self.latest[i] = data
        self.t_rx[i] = t
        return True

    def push_msg(self, msg, t: float) -> bool:
        return self.push(msg.arbitration_id, msg.data, t, msg.is_extended_id,
                         msg.is_remote_frame or msg.is_error_frame)
