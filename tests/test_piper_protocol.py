"""Piper codec: golden bytes worked out by hand from the wire spec, round trips, garbage robustness."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.piper import protocol as P
from hardware.piper.command_decoder import PiperCommandDecoder, decode_mode
from hardware.types import STATUS_COLLISION, STATUS_COMM_LOST, STATUS_ENABLED, STATUS_LIMIT, STATUS_OVERTEMP


def h(s: str) -> bytes:
    return bytes.fromhex(s.replace(" ", ""))


# ---- golden bytes (derivations in the comments) ----------------------------------------------------------
def test_mode_frames():
    # ctrl 0x01 CAN, move 0x01 J, speed 100 = 0x64, mit 0x00
    assert P.encode_mode(P.MOVE_J, 100, P.MIT_MODE_POSVEL) == h("01 01 64 00 00 00 00 00")
    assert P.encode_mode(P.MOVE_MIT, 50, P.MIT_MODE_MIT) == h("01 04 32 AD 00 00 00 00")
    assert P.encode_mode(P.MOVE_J, 250) == h("01 01 64 00 00 00 00 00")  # speed clamps to 100 %


def test_joint_targets():
    # 90 deg = 90000 = 0x00015F90; -45 deg = -45000 = 0xFFFF5038; 1 deg = 0x3E8; -0.001 deg = -1;
    # 180 deg = 180000 = 0x2BF20
    q = [math.pi / 2, -math.pi / 4, 0.0, math.radians(1), math.radians(-0.001), math.pi]
    f1, f2, f3 = P.encode_joint_targets(q)
    assert f1 == h("00 01 5F 90 FF FF 50 38")
    assert f2 == h("00 00 00 00 00 00 03 E8")
    assert f3 == h("FF FF FF FF 00 02 BF 20")
    assert P.decode_joint_pair(f1) == pytest.approx((math.pi / 2, -math.pi / 4))


def test_gripper_enable_query_frames():
    # 0.05 m = 50000 um = 0xC350; 1.5 N*m = 1500 = 0x05DC; code 1 enable
    assert P.encode_gripper(0.05, 1.5, P.GRIPPER_ENABLE) == h("00 00 C3 50 05 DC 01 00")
    # effort clamps to 5 N*m = 5000 = 0x1388
    assert P.encode_gripper(0.0, 9.0, P.GRIPPER_DISABLE_CLEAR, P.GRIPPER_SET_ZERO) == h("00000000 1388 02 AE")
    assert P.encode_enable(True) == h("07 02 00 00 00 00 00 00")
    assert P.encode_enable(False, motor=3) == h("03 01 00 00 00 00 00 00")
    assert P.encode_param_query(4, 1) == h("04 01 00 00 00 00 00 00")


def test_mit_golden():
    # all zero: p = int(12.5*65535/25) = 32767 = 7FFF; v = int(45*4095/90) = 2047 = 7FF; kp = 0;
    # kd = int(5*4095/10) = 7FF; t = int(8*255/16) = 127 = 7F.
    # B0 7F B1 FF B2 7F B3 F0 B4 00 B5 7F B6 (F<<4)|(7F>>4) = F7; crc = xor(B0..B6) & F = 0x87 & F = 7;
    # B7 = (7F & F) << 4 | 7 = F7
    assert P.encode_mit(0, 0, 0, 0, 0) == h("7F FF 7F F0 00 7F F7 F7")
    assert P.encode_mit(12.5, 45, 500, 5, 8) == h("FF" * 8)  # all ones, crc = xor of seven FF = F
    assert P.encode_mit(-12.5, -45, 0, -5, -8) == h("00" * 8)
    assert P.encode_mit(-12.5, 45, 0, 5, -8) == h("00 00 FF F0 00 FF F0 00")  # crc = 0
    assert P.encode_mit(99, -99, 1e9, -1e9, float("nan")) == P.encode_mit(12.5, -45, 500, -5, -8)  # clamped
    assert P.mit_crc_ok(h("7F FF 7F F0 00 7F F7 F7")) and not P.mit_crc_ok(h("7F FF 7F F0 00 7F F7 F6"))


def test_feedback_golden():
    # 0x2A8: stroke 50000 um, effort 1000 = 1.0 N*m, status 0x40
    assert P.decode_gripper_fb(h("00 00 C3 50 03 E8 40 00")) == pytest.approx((0.05, 1.0, 0x40))
    # 0x251: speed 1500 -> 1.5 rad/s, current 0xF830 = -2000 -> -2 A, pos 0xFFFFFE0C = -500 -> -0.5 rad
    assert P.decode_high_speed(h("05 DC F8 30 FF FF FE 0C")) == pytest.approx((1.5, -2.0, -0.5))
    assert P.encode_high_speed(1.5, -2.0, -0.5) == h("05 DC F8 30 FF FF FE 0C")
    # 0x261: 240 -> 24.0 V, driver 35 degC, motor 0xFB = -5 degC, status 0x42, bus 1234 mA
    v, td, tm, bits, ib = P.decode_low_speed(h("00 F0 00 23 FB 42 04 D2"))
    assert (v, td, tm, bits, ib) == pytest.approx((24.0, 35, -5, 0x42, 1.234))
    assert P.low_speed_flags(bits) == STATUS_OVERTEMP | STATUS_ENABLED
    assert P.encode_low_speed(24.0, 35, -5, 0x42, 1.234) == h("00 F0 00 23 FB 42 04 D2")
    # 0x2A1: arm_status 7 (collision), limit bits 0b101, comm bits 0b010
    f = P.decode_status(h("01 07 01 00 00 00 05 02"))
    flags = P.status_flags(f[1], f[6], f[7])
    assert flags[0] == STATUS_COLLISION | STATUS_LIMIT and flags[1] == STATUS_COLLISION | STATUS_COMM_LOST
    assert flags[2] == STATUS_COLLISION | STATUS_LIMIT and flags[3] == STATUS_COLLISION


def test_effort_constants_and_old_firmware():
    assert P.effort_per_amp(False) == (1.18125,) * 3 + (0.95844,) * 3
    assert P.effort_per_amp(True) == (4.725,) * 3 + (0.95844,) * 3


def test_end_pose_and_params_and_firmware():
    pose = (0.1, -0.2, 0.3, 0.5, -1.0, 3.0)
    assert P.decode_end_pose(P.encode_end_pose(pose)) == pytest.approx(pose, abs=1e-5)  # 0.001 deg
    m, hi, lo, v = P.decode_param_limits(P.encode_param_limits(2, math.pi, 0.0, 3.0))
    assert (m, hi, lo, v) == pytest.approx((2, math.pi, 0.0, 3.0), abs=1e-3)
    chunks = P.encode_firmware_reply("S-V1.6-3")
    assert all(len(c) == 8 for c in chunks) and P.firmware_complete(b"".join(chunks))
    assert P.parse_firmware(b"\x00xxS-V1.8-2\x00\x00") == "S-V1.8-2" and P.parse_firmware(b"junk") is None


# ---- round trips -----------------------------------------------------------------------------------------
angles = st.floats(-3.5, 3.5)


@given(st.lists(angles, min_size=6, max_size=6))
def test_joint_target_roundtrip(q):
    frames = P.encode_joint_targets(q)
    back = [x for f in frames for x in P.decode_joint_pair(f)]
    np.testing.assert_allclose(back, q, atol=0.5e-3 * math.pi / 180 + 1e-12)


@given(st.floats(-12.5, 12.5), st.floats(-45, 45), st.floats(0, 500), st.floats(-5, 5), st.floats(-8, 8))
def test_mit_roundtrip(q, v, kp, kd, t):
    d = P.encode_mit(q, v, kp, kd, t)
    assert P.mit_crc_ok(d)
    out = P.decode_mit(d)
    steps = (25 / 65535, 90 / 4095, 500 / 4095, 10 / 4095, 16 / 255)  # truncation: error < one step, below
    for x, y, s in zip((q, v, kp, kd, t), out, steps, strict=True):
        assert x - s - 1e-9 <= y <= x + 1e-9


@given(st.floats(-30, 30), st.floats(-30, 30), st.floats(-3, 3))
def test_high_speed_roundtrip(v, c, p):
    back = P.decode_high_speed(P.encode_high_speed(v, c, p))
    np.testing.assert_allclose(back, (v, c, p), atol=5.01e-4)


# ---- garbage ---------------------------------------------------------------------------------------------
@settings(max_examples=300)
@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8), st.booleans(), st.booleans())
def test_decoders_never_raise_on_garbage(arb_id, data, ext, special):
    fb, cmd = P.PiperFeedbackDecoder(), PiperCommandDecoder()
    fb.push(arb_id, data, 0.0, ext, special)
    cmd.decode(arb_id, data, ext, special)
    assert fb.counters.ok + fb.counters.rejected == 1
    assert cmd.counters.ok + cmd.counters.rejected == 1


_FRAME = st.tuples(st.one_of(st.sampled_from(sorted(P.FEEDBACK_IDS)), st.integers(0, 0x7FF)),
                   st.binary(min_size=0, max_size=9), st.booleans(), st.booleans())


@settings(max_examples=300)
@given(st.lists(_FRAME, max_size=12))
def test_push_frames_is_push_of_each(frames):
    """One drain's frames at once (the twin's feedback stream) keep, count and reject as push() per frame."""
    one, many = P.PiperFeedbackDecoder(), P.PiperFeedbackDecoder()
    for arb_id, data, ext, special in frames:
        one.push(arb_id, data, 0.25, ext, special)
    many.push_frames(frames, 0.25)
    assert many.latest == one.latest and many.t_rx == one.t_rx and many.firmware_buf == one.firmware_buf
    assert many.counters.as_dict() == one.counters.as_dict()


@given(st.binary(min_size=8, max_size=8))
def test_every_8_byte_payload_decodes(d):
    P.decode_status(d), P.decode_joint_pair(d), P.decode_gripper_fb(d), P.decode_high_speed(d)
    P.decode_low_speed(d), P.decode_mit(d), decode_mode(d), P.decode_param_limits(d), P.decode_param_acc(d)


def test_command_decoder_counts_rejections():
    dec = PiperCommandDecoder()
    good = P.encode_mit(0.1, 0, 10, 1, 0.5)
    bad = good[:7] + bytes(((good[7] & 0xF0) | ((good[7] + 1) & 0xF),))
    assert dec.decode(P.ID_MIT[2], good)[0] == "mit"
    assert dec.decode(P.ID_MIT[2], bad) is None
    assert dec.decode(P.ID_JOINT_TARGET[0], good[:7]) is None
    assert dec.decode(0x300, good) is None
    c = dec.counters
    assert (c.ok, c.bad_crc, c.bad_dlc, c.unknown_id) == (1, 1, 1, 1)
