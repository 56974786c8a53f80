"""AgileX Piper CAN protocol: every id, scale and bit of the wire in one place, as pure codec functions.

Classic CAN, 11-bit ids, DLC 8, multi-byte fields big-endian (source: shared/reference/hardware-protocols.md).
Encoders return 8 bytes. Decoders take 8 bytes and return plain Python numbers in SI units (rad, rad/s, A,
N*m, m, V, degC). PiperFeedbackDecoder, the driver's stateful front end, validates (DLC, known id), counts
what it rejects, never raises (the emulators' is command_decoder.py, with the arm side's decoders).
"""

from __future__ import annotations

import math
import struct

from hardware.can_bus import RejectCounters, float_to_uint, frame_ok, uint_to_float
from hardware.types import (
    STATUS_COLLISION,
    STATUS_COMM_LOST,
    STATUS_DRIVER_ERROR,
    STATUS_ENABLED,
    STATUS_LIMIT,
    STATUS_OVERCURRENT,
    STATUS_OVERTEMP,
    STATUS_STALL,
    STATUS_UNDERVOLTAGE,
)

N_JOINTS = 6
FRAME_DLC = 8

# ---- ids: host -> arm ------------------------------------------------------------------------------------
ID_MODE = 0x151
ID_JOINT_TARGET = (0x155, 0x156, 0x157)  # J1,J2 / J3,J4 / J5,J6
ID_GRIPPER_CMD = 0x159
ID_MIT = tuple(range(0x15A, 0x160))  # one per joint 1..6
ID_ENABLE = 0x471
ID_PARAM_QUERY = 0x472
ID_PARAM_REPLY_LIMITS = 0x473  # angle limits + max speed of one motor
ID_PARAM_REPLY_ACC = 0x47C  # max acceleration of one motor
ID_FIRMWARE = 0x4AF  # query (host -> arm) and ASCII reply chunks (arm -> host); reply layout unverified

# ---- ids: arm -> host ------------------------------------------------------------------------------------
ID_STATUS = 0x2A1
ID_END_POSE = (0x2A2, 0x2A3, 0x2A4)  # (X, Y) / (Z, RX) / (RY, RZ)
ID_JOINT_FB = (0x2A5, 0x2A6, 0x2A7)  # joint angle pairs like ID_JOINT_TARGET
ID_GRIPPER_FB = 0x2A8
ID_HIGH_SPEED = tuple(range(0x251, 0x257))  # per motor 1..6
ID_LOW_SPEED = tuple(range(0x261, 0x267))  # per motor 1..6
FEEDBACK_IDS = frozenset((ID_STATUS, *ID_END_POSE, *ID_JOINT_FB, ID_GRIPPER_FB, *ID_HIGH_SPEED, *ID_LOW_SPEED,
                          ID_PARAM_REPLY_LIMITS, ID_PARAM_REPLY_ACC, ID_FIRMWARE))
_PLAIN_FEEDBACK_IDS = FEEDBACK_IDS - {ID_FIRMWARE}  # kept as they come (the firmware reply is accumulated)
COMMAND_IDS = frozenset((ID_MODE, *ID_JOINT_TARGET, ID_GRIPPER_CMD, *ID_MIT, ID_ENABLE, ID_PARAM_QUERY,
                         ID_FIRMWARE))

# ---- arm facts ------------------------------------------------------------------------------------------
JOINT_LIMITS_DEG = ((-150.0, 150.0), (0.0, 180.0), (-170.0, 0.0), (-100.0, 100.0), (-70.0, 70.0),
                    (-120.0, 120.0))  # vendor J1..J6 ranges
ARM_FEEDBACK_FRAMES_S = 3040.0  # frames/s the arm sends: 8 ids x 200 Hz + 6 x 200 Hz + 6 x 40 Hz (reference)

# ---- 0x151 mode ------------------------------------------------------------------------------------------
CTRL_STANDBY, CTRL_CAN = 0x00, 0x01
MOVE_P, MOVE_J, MOVE_L, MOVE_C, MOVE_MIT, MOVE_CPV = 0, 1, 2, 3, 4, 5
MIT_MODE_POSVEL, MIT_MODE_MIT = 0x00, 0xAD
INSTALL_UNSET = 0x00  # B5 install pose: 0 leaves the arm's setting alone (1 upright, 2 left, 3 right)

# ---- 0x471 enable ----------------------------------------------------------------------------------------
MOTOR_ALL = 7
ENABLE_CODE, DISABLE_CODE = 0x02, 0x01

# ---- 0x159 gripper ---------------------------------------------------------------------------------------
GRIPPER_DISABLE, GRIPPER_ENABLE, GRIPPER_DISABLE_CLEAR, GRIPPER_ENABLE_CLEAR = 0, 1, 2, 3
GRIPPER_SET_ZERO = 0xAE
GRIPPER_EFFORT_MAX_NM = 5.0  # 0..5000 in 0.001 N*m

# ---- scales ----------------------------------------------------------------------------------------------
MDEG_PER_RAD = 180_000.0 / math.pi  # joint angles: 0.001 deg
UM_PER_M = 1e6  # gripper stroke: 0.001 mm
MILLI = 1e-3  # 0.001 rad, rad/s, A, N*m
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1

# ---- MIT (0x15A..0x15F) ----------------------------------------------------------------------------------
MIT_P_MIN, MIT_P_MAX = -12.5, 12.5  # rad, 16 bit
MIT_V_MIN, MIT_V_MAX = -45.0, 45.0  # rad/s, 12 bit
MIT_KP_MIN, MIT_KP_MAX = 0.0, 500.0  # N*m/rad, 12 bit
MIT_KD_MIN, MIT_KD_MAX = -5.0, 5.0  # N*m*s/rad, 12 bit
MIT_T_MIN, MIT_T_MAX = -8.0, 8.0  # N*m on the wire, 8 bit
# Vendor FAQ: the motor executes 4x the commanded MIT torque. The driver divides tau_ff by this before
# encoding (so the wire range +-8 is +-32 N*m at the joint); the emulator multiplies it back, like the arm.
MIT_TORQUE_GAIN = 4.0

# ---- effort from current (vendor SDK): tau [N*m] = current [A] * K --------------------------------------
EFFORT_PER_AMP = (1.18125, 1.18125, 1.18125, 0.95844, 0.95844, 0.95844)  # N*m/A, J1..J6
OLD_FIRMWARE_EFFORT_X4 = (4.0, 4.0, 4.0, 1.0, 1.0, 1.0)  # firmware <= 1.8-2 reports J1-J3 4x low

# ---- 0x261..0x266 status byte -> hardware.types STATUS_* -------------------------------------------------
LOW_SPEED_STATUS_MAP = (  # (vendor bit, our flag)
    (0, STATUS_UNDERVOLTAGE), (1, STATUS_OVERTEMP), (2, STATUS_OVERCURRENT), (3, STATUS_OVERTEMP),
    (4, STATUS_COLLISION), (5, STATUS_DRIVER_ERROR), (6, STATUS_ENABLED), (7, STATUS_STALL),
)
# 0x2A1 arm_status codes that concern every joint
ARM_STATUS_ESTOP, ARM_STATUS_COMM_ERROR, ARM_STATUS_COLLISION = 0x01, 0x05, 0x07
ARM_STATUS_FLAGS = {ARM_STATUS_ESTOP: STATUS_DRIVER_ERROR, ARM_STATUS_COMM_ERROR: STATUS_COMM_LOST,
                    ARM_STATUS_COLLISION: STATUS_COLLISION}

_S_MODE = struct.Struct(">BBBBBBxx")
_S_II = struct.Struct(">ii")
_S_6I = struct.Struct(">6i")  # the three joint-target frames' pairs back to back
_S_GRIP_CMD = struct.Struct(">iHBB")
_S_ENABLE = struct.Struct(">BBxxxxxx")
_S_STATUS = struct.Struct(">BBBBBBBB")
_S_GRIP_FB = struct.Struct(">ihBx")
_S_HIGH = struct.Struct(">hhi")
_S_LOW = struct.Struct(">HhbBH")
# the feedback frames' layouts, for a driver's decode of a whole sample in one pass (piper/follower.py):
# decode_joint_pair, decode_high_speed and decode_low_speed's unpacks
S_JOINT_PAIR, S_HIGH_SPEED, S_LOW_SPEED = _S_II, _S_HIGH, _S_LOW
_S_QUERY = struct.Struct(">BBxxxxxx")
_S_LIMITS = struct.Struct(">BhhHx")
_S_ACC = struct.Struct(">BHxxxxx")


def _i32(x: float) -> int:
    v = round(x)
    return INT32_MIN if v < INT32_MIN else INT32_MAX if v > INT32_MAX else v


def _i16(x: float) -> int:
    v = round(x)
    return -32768 if v < -32768 else 32767 if v > 32767 else v


# ---- host -> arm -----------------------------------------------------------------------------------------
def encode_mode(move_mode: int = MOVE_J, speed_pct: int = 100, mit_mode: int = MIT_MODE_POSVEL,
                ctrl_mode: int = CTRL_CAN, residence_s: int = 0, install: int = INSTALL_UNSET) -> bytes:
    speed = max(0, min(100, int(speed_pct)))
    return _S_MODE.pack(ctrl_mode, move_mode, speed, mit_mode, residence_s, install)


def encode_joint_targets(q_rad) -> tuple[bytes, bytes, bytes]:
    """Six joint targets [rad] -> the three frames for ID_JOINT_TARGET (int32 pairs, 0.001 deg)."""
    # _i32 over plain floats (tolist(): the same values; round() as float.__round__, not looked up per call):
    # the 500 Hz command; the six int32 in one pack, cut into the three frames' pairs (one ">ii" each's bytes)
    xs = q_rad.tolist() if hasattr(q_rad, "tolist") else [float(x) for x in q_rad]
    b = _S_6I.pack(*[v if INT32_MIN <= (v := float.__round__(x * MDEG_PER_RAD)) <= INT32_MAX
                     else INT32_MIN if v < INT32_MIN else INT32_MAX for x in xs])
    return b[:8], b[8:16], b[16:]


def encode_gripper(stroke_m: float, effort_nm: float = 1.0, code: int = GRIPPER_ENABLE,
                   set_zero: int = 0) -> bytes:
    eff = int(round(max(0.0, min(GRIPPER_EFFORT_MAX_NM, effort_nm)) * 1000))
    return _S_GRIP_CMD.pack(_i32(stroke_m * UM_PER_M), eff, code, set_zero)


def encode_enable(enable: bool, motor: int = MOTOR_ALL) -> bytes:
    return _S_ENABLE.pack(motor, ENABLE_CODE if enable else DISABLE_CODE)


def encode_param_query(motor: int, kind: int = 1) -> bytes:
    """0x472: kind 1 -> angle limits + max speed (reply 0x473), kind 2 -> max acceleration (reply 0x47C)."""
    return _S_QUERY.pack(motor, kind)


def encode_firmware_query() -> bytes:
    return bytes((0x01, 0, 0, 0, 0, 0, 0, 0))


def encode_mit(q: float, v: float, kp: float, kd: float, t: float) -> bytes:
    """One MIT frame (ID_MIT[j]): wire torque t [N*m] BEFORE the firmware's x4 (see MIT_TORQUE_GAIN)."""
    p = float_to_uint(q, MIT_P_MIN, MIT_P_MAX, 16)
    vv = float_to_uint(v, MIT_V_MIN, MIT_V_MAX, 12)
    kpu = float_to_uint(kp, MIT_KP_MIN, MIT_KP_MAX, 12)
    kdu = float_to_uint(kd, MIT_KD_MIN, MIT_KD_MAX, 12)
    tu = float_to_uint(t, MIT_T_MIN, MIT_T_MAX, 8)
    b0, b1, b2 = p >> 8, p & 0xFF, vv >> 4
    b3, b4, b5 = ((vv & 0xF) << 4) | (kpu >> 8), kpu & 0xFF, kdu >> 4
    b6 = ((kdu & 0xF) << 4) | (tu >> 4)
    crc = (b0 ^ b1 ^ b2 ^ b3 ^ b4 ^ b5 ^ b6) & 0xF
    return bytes((b0, b1, b2, b3, b4, b5, b6, ((tu & 0xF) << 4) | crc))


def mit_crc_ok(d: bytes) -> bool:
    return (d[0] ^ d[1] ^ d[2] ^ d[3] ^ d[4] ^ d[5] ^ d[6]) & 0xF == d[7] & 0xF


def decode_mit(d: bytes) -> tuple[float, float, float, float, float]:
    """MIT frame -> (q rad, v rad/s, kp, kd, wire torque N*m). The caller checks mit_crc_ok first."""
    p = (d[0] << 8) | d[1]
    vv = (d[2] << 4) | (d[3] >> 4)
    kpu = ((d[3] & 0xF) << 8) | d[4]
    kdu = (d[5] << 4) | (d[6] >> 4)
    tu = ((d[6] & 0xF) << 4) | (d[7] >> 4)
    return (uint_to_float(p, MIT_P_MIN, MIT_P_MAX, 16), uint_to_float(vv, MIT_V_MIN, MIT_V_MAX, 12),
            uint_to_float(kpu, MIT_KP_MIN, MIT_KP_MAX, 12), uint_to_float(kdu, MIT_KD_MIN, MIT_KD_MAX, 12),
            uint_to_float(tu, MIT_T_MIN, MIT_T_MAX, 8))


def decode_joint_pair(d: bytes) -> tuple[float, float]:
    """Int32 pair in 0.001 deg (0x155-0x157 targets and 0x2A5-0x2A7 feedback) -> rad."""
    a, b = _S_II.unpack(d)
    return a / MDEG_PER_RAD, b / MDEG_PER_RAD


# ---- arm -> host -----------------------------------------------------------------------------------------
def encode_status(ctrl_mode: int, arm_status: int, mode_feed: int, limit_bits: int = 0, comm_bits: int = 0,
                  teach: int = 0, motion: int = 0, trajectory: int = 0) -> bytes:
    return _S_STATUS.pack(ctrl_mode, arm_status, mode_feed, teach, motion, trajectory, limit_bits, comm_bits)


def decode_status(d: bytes) -> tuple[int, int, int, int, int, int, int, int]:
    """(ctrl_mode, arm_status, mode_feed, teach, motion, trajectory, limit_bits, comm_bits); bit j-1 of
    limit_bits / comm_bits is joint j over its angle limit / with a communication error."""
    return _S_STATUS.unpack(d)


def encode_joint_pair(a_rad: float, b_rad: float) -> bytes:
    # _i32 written out: the feedback encoders run ~1,400 times per simulated second in the twin
    a, b = round(a_rad * MDEG_PER_RAD), round(b_rad * MDEG_PER_RAD)
    return _S_II.pack(INT32_MIN if a < INT32_MIN else INT32_MAX if a > INT32_MAX else a,
                      INT32_MIN if b < INT32_MIN else INT32_MAX if b > INT32_MAX else b)


def encode_end_pose_pair(a: float, b: float) -> bytes:
    """End pose pair: X, Y, Z in 0.001 mm (a, b given in m) for 0x2A2 and the first of 0x2A3; RX, RY, RZ in
    0.001 deg (given in rad). The caller converts: use encode_end_pose for the three frames."""
    return _S_II.pack(_i32(a), _i32(b))


def encode_end_pose(pose) -> tuple[bytes, bytes, bytes]:
    """pose = (x, y, z [m], rx, ry, rz [rad]) -> frames for ID_END_POSE."""
    x, y, z, rx, ry, rz = (float(v) for v in pose)
    return (encode_end_pose_pair(x * UM_PER_M, y * UM_PER_M),
            encode_end_pose_pair(z * UM_PER_M, rx * MDEG_PER_RAD),
            encode_end_pose_pair(ry * MDEG_PER_RAD, rz * MDEG_PER_RAD))


def decode_end_pose(frames) -> tuple[float, float, float, float, float, float]:
    """Three frames of ID_END_POSE -> (x, y, z [m], rx, ry, rz [rad])."""
    (x, y), (z, rx), (ry, rz) = (_S_II.unpack(f) for f in frames)
    return (x / UM_PER_M, y / UM_PER_M, z / UM_PER_M, rx / MDEG_PER_RAD, ry / MDEG_PER_RAD, rz / MDEG_PER_RAD)


def encode_gripper_fb(stroke_m: float, effort_nm: float, status: int = 0) -> bytes:
    return _S_GRIP_FB.pack(_i32(stroke_m * UM_PER_M), _i16(effort_nm * 1000), status)


def decode_gripper_fb(d: bytes) -> tuple[float, float, int]:
    """(stroke m, effort N*m, status byte)."""
    s, e, st = _S_GRIP_FB.unpack(d)
    return s / UM_PER_M, e * MILLI, st


def encode_high_speed(speed_rad_s: float, current_a: float, pos_rad: float) -> bytes:
    v, c, p = round(speed_rad_s * 1000), round(current_a * 1000), round(pos_rad * 1000)  # _i16, _i16, _i32
    return _S_HIGH.pack(-32768 if v < -32768 else 32767 if v > 32767 else v,
                        -32768 if c < -32768 else 32767 if c > 32767 else c,
                        INT32_MIN if p < INT32_MIN else INT32_MAX if p > INT32_MAX else p)


def decode_high_speed(d: bytes) -> tuple[float, float, float]:
    """(speed rad/s, current A signed, position rad)."""
    v, c, p = _S_HIGH.unpack(d)
    return v * MILLI, c * MILLI, p * MILLI


def encode_low_speed(voltage_v: float, driver_temp_c: float, motor_temp_c: float, status_bits: int,
                     bus_current_a: float) -> bytes:
    return _S_LOW.pack(max(0, min(65535, round(voltage_v * 10))), _i16(driver_temp_c),
                       max(-128, min(127, round(motor_temp_c))), status_bits & 0xFF,
                       max(0, min(65535, round(bus_current_a * 1000))))


def decode_low_speed(d: bytes) -> tuple[float, int, int, int, float]:
    """(voltage V, driver temp degC, motor temp degC, vendor status bits, bus current A)."""
    v, td, tm, st, ib = _S_LOW.unpack(d)
    return v * 0.1, td, tm, st, ib * MILLI


def low_speed_flags(status_bits: int) -> int:
    """Vendor 0x261-0x266 status byte -> hardware.types STATUS_* flags."""
    out = 0
    for bit, flag in LOW_SPEED_STATUS_MAP:
        if status_bits >> bit & 1:
            out |= flag
    return out


def flags_to_low_speed(flags: int, enabled: bool) -> int:
    """Emulators: STATUS_* flags (+ enabled) -> vendor status byte (first vendor bit per flag)."""
    bits = 1 << 6 if enabled else 0
    done = STATUS_ENABLED
    for bit, flag in LOW_SPEED_STATUS_MAP:
        if flags & flag and not done & flag:
            bits |= 1 << bit
            done |= flag
    return bits


def status_flags(arm_status: int, limit_bits: int, comm_bits: int) -> list[int]:
    """0x2A1 -> per-joint STATUS_* flags (arm-wide codes go to every joint, bit j-1 to joint j)."""
    base = ARM_STATUS_FLAGS.get(arm_status, 0)
    return [base | (STATUS_LIMIT if limit_bits >> j & 1 else 0)
            | (STATUS_COMM_LOST if comm_bits >> j & 1 else 0) for j in range(N_JOINTS)]


def encode_param_limits(motor: int, max_angle_rad: float, min_angle_rad: float,
                        max_speed_rad_s: float) -> bytes:
    """0x473 reply: int16 angles in 0.1 deg, uint16 max speed 0.001 rad/s (layout from the vendor SDK)."""
    d = math.degrees
    return _S_LIMITS.pack(motor, _i16(d(max_angle_rad) * 10), _i16(d(min_angle_rad) * 10),
                          max(0, min(65535, round(max_speed_rad_s * 1000))))


def decode_param_limits(d: bytes) -> tuple[int, float, float, float]:
    """(motor, max angle rad, min angle rad, max speed rad/s)."""
    m, a_max, a_min, v = _S_LIMITS.unpack(d)
    return m, math.radians(a_max / 10), math.radians(a_min / 10), v * MILLI


def encode_param_acc(motor: int, max_acc_rad_s2: float) -> bytes:
    return _S_ACC.pack(motor, max(0, min(65535, round(max_acc_rad_s2 * 100))))


def decode_param_acc(d: bytes) -> tuple[int, float]:
    """(motor, max acceleration rad/s^2), unit 0.01 rad/s^2."""
    m, a = _S_ACC.unpack(d)
    return m, a * 0.01


def effort_per_amp(firmware_effort_x4: bool) -> tuple[float, ...]:
    """Per-joint N*m/A that turns 0x251-0x256 current into joint torque (old firmware: J1-J3 x4)."""
    if not firmware_effort_x4:
        return EFFORT_PER_AMP
    return tuple(k * f for k, f in zip(EFFORT_PER_AMP, OLD_FIRMWARE_EFFORT_X4, strict=True))


def firmware_complete(buf: bytes) -> bool:
    """True once the reply holds 'S-V' followed by a terminator (NUL, space, newline) or 32 characters."""
    i = buf.find(b"S-V")
    return i >= 0 and (any(c < 0x21 or c > 0x7E for c in buf[i:]) or len(buf) - i >= 32)


def encode_firmware_reply(text: str) -> list[bytes]:
    """Emulators: firmware text -> 8-byte 0x4AF chunks, NUL padded (at least one NUL terminates it)."""
    raw = text.encode("ascii") + b"\x00"
    raw += b"\x00" * (-len(raw) % FRAME_DLC)
    return [raw[k:k + FRAME_DLC] for k in range(0, len(raw), FRAME_DLC)]


def parse_firmware(buf: bytes) -> str | None:
    """Firmware version text from the concatenated 0x4AF reply bytes ('S-V1.6-3' style), None if absent."""
    i = buf.find(b"S-V")
    if i < 0:
        return None
    out = bytearray()
    for c in buf[i:]:
        if c < 0x21 or c > 0x7E:
            break
        out.append(c)
    return out.decode("ascii")


# ---- validating front ends (count and reject, never raise) -----------------------------------------------
class PiperFeedbackDecoder:
    """Host side: keeps the latest valid raw frame and its receive time [s] per feedback id.

    push() is the cheap per-frame call of a drain loop (no decoding); the driver decodes only the newest
    frame of each id. Firmware reply chunks (0x4AF) are accumulated in firmware_buf."""

    def __init__(self):
        self.counters = RejectCounters()
        self.latest: dict[int, bytes] = {}
        self.t_rx: dict[int, float] = {}
        self.firmware_buf = bytearray()

    def push(self, arb_id: int, data, t: float, is_ext: bool = False, is_special: bool = False) -> bool:
        if not frame_ok(self.counters, FEEDBACK_IDS, arb_id, data, is_ext, is_special):
            return False
        self.counters.ok += 1
        if arb_id == ID_FIRMWARE:
            self.firmware_buf += bytes(data)
            del self.firmware_buf[:-256]  # bounded
        self.latest[arb_id] = data
        self.t_rx[arb_id] = t
        return True

    def push_frames(self, frames, t: float) -> None:
        """push() of each (arb_id, data, is_ext, is_special) of one drain, received by t [s]: the usual
        frame (a known feedback id, standard, 8 bytes) kept inline, any other through push()."""
        latest, t_rx, ids, ok = self.latest, self.t_rx, _PLAIN_FEEDBACK_IDS, 0
        for arb_id, data, is_ext, is_special in frames:
            if is_ext or is_special or arb_id not in ids or len(data) != FRAME_DLC:
                self.push(arb_id, data, t, is_ext, is_special)
                continue
            ok += 1
            latest[arb_id] = data
            t_rx[arb_id] = t
        self.counters.ok += ok  # once: push() counts its own frames, so the total is the same

    def push_msg(self, msg, t: float) -> bool:
        return self.push(msg.arbitration_id, msg.data, t, msg.is_extended_id,
                         msg.is_remote_frame or msg.is_error_frame)
