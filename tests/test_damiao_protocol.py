"""Damiao codec: golden bytes worked out by hand from the wire spec, round trips, garbage robustness."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.damiao import protocol as D
from hardware.types import STATUS_COMM_LOST, STATUS_ENABLED, STATUS_OVERTEMP, STATUS_UNDERVOLTAGE

R4310 = D.MODELS["DM4310"].ranges  # 12.5 rad, 30 rad/s, 10 N*m
R4340 = D.MODELS["DM4340"].ranges  # 12.5 rad, 8 rad/s, 28 N*m


def h(s: str) -> bytes:
    return bytes.fromhex(s.replace(" ", ""))


def test_mit_golden():
    # p = int(12.5*65535/25) = 32767 = 7FFF; v = int(30*4095/60) = 2047 = 7FF; kp = kd = 0;
    # t = int(10*4095/20) = 2047 = 7FF. D3 = (F<<4)|0, D5 = 0, D6 = (0<<4)|(7FF>>8) = 07, D7 = FF
    assert D.encode_mit(0, 0, 0, 0, 0, R4310) == h("7F FF 7F F0 00 00 07 FF")
    # kp 500 -> FFF, kd 5 -> FFF: D3 = F0|F, D4 = FF, D5 = FF, D6 = F0|7
    assert D.encode_mit(0, 0, 500, 5, 0, R4310) == h("7F FF 7F FF FF FF F7 FF")
    assert D.encode_mit(12.5, 30, 500, 5, 10, R4310) == h("FF" * 8)
    assert D.encode_mit(-99, -99, -1, -1, -99, R4310) == h("00" * 8)  # clamped to the minima
    # the same torque maps to different bits with another TMAX: 14 N*m of 28 -> int(42*4095/56) = 3071 = BFF
    assert D.encode_mit(0, 0, 0, 0, 14.0, R4340)[6:] == h("0B FF")


def test_feedback_golden():
    # D0 0x11: ERR 1 (enabled), id 1. p 7FFF -> 32767*25/65535 - 12.5; v 7FF -> 2047*60/4095 - 30;
    # t 7FF -> 2047*20/4095 - 10; MOS 40 degC, rotor 45 degC
    sid, err, q, v, tau, tm, tr = D.decode_feedback(h("11 7F FF 7F F7 FF 28 2D"), R4310)
    assert (sid, err, tm, tr) == (1, 1, 40, 45)
    assert q == pytest.approx(32767 * 25 / 65535 - 12.5)
    assert v == pytest.approx(2047 * 60 / 4095 - 30)
    assert tau == pytest.approx(2047 * 20 / 4095 - 10)
    assert D.encode_feedback(1, 1, q, v, tau, 40, 45, R4310) == h("11 7F FF 7F F7 FF 28 2D")


def test_special_and_register_frames():
    assert D.special_frame(D.CODE_ENABLE) == h("FF FF FF FF FF FF FF FC")
    assert D.special_frame(D.CODE_DISABLE) == h("FF FF FF FF FF FF FF FD")
    assert D.special_frame(D.CODE_SAVE_ZERO) == h("FF FF FF FF FF FF FF FE")
    assert D.special_frame(D.CODE_CLEAR_ERROR) == h("FF FF FF FF FF FF FF FB")
    assert D.special_code(h("FF FF FF FF FF FF FF FC")) == D.CODE_ENABLE
    assert D.special_code(h("FF FF FF FF FF FF FF 00")) is None
    assert D.encode_reg_read(1, D.RID_VMAX) == h("01 00 33 16 00 00 00 00")  # rid 22 = 0x16
    assert D.encode_reg_write(2, D.RID_TIMEOUT, 1000) == h("02 00 55 09 E8 03 00 00")  # 1000 = 0x3E8 LE
    assert D.encode_reg_save(3) == h("03 00 AA 00 00 00 00 00")
    # float32 12.5 = 0x41480000, little-endian on the wire
    assert D.encode_reg_reply(1, D.REG_READ, D.RID_PMAX, 12.5) == h("01 00 33 15 00 00 48 41")
    assert D.decode_reg_reply(h("01 00 33 15 00 00 48 41"), 1) == (D.RID_PMAX, 12.5)
    assert D.decode_reg_reply(h("01 00 33 15 00 00 48 41"), 2) is None  # another motor's reply
    assert D.decode_reg_request(h("02 00 55 09 E8 03 00 00")) == (2, D.REG_WRITE, D.RID_TIMEOUT, 1000)
    assert D.timeout_register(0.4) == 8000  # the reference: 8000 x 50 us = 400 ms


def test_err_flags():
    assert D.err_flags(D.ERR_ENABLED) == STATUS_ENABLED
    assert D.err_flags(D.ERR_DISABLED) == 0
    assert D.err_flags(D.ERR_UNDERVOLTAGE) == STATUS_UNDERVOLTAGE
    assert D.err_flags(D.ERR_COIL_OVERTEMP) == D.err_flags(D.ERR_MOS_OVERTEMP) == STATUS_OVERTEMP
    assert D.err_flags(D.ERR_COMM_LOST) == STATUS_COMM_LOST


def test_unknown_model_names_known_ones():
    with pytest.raises(KeyError, match="DM4310"):
        D.motor_model("DM9999")


@given(st.floats(-12.5, 12.5), st.floats(-8, 8), st.floats(0, 500), st.floats(0, 5), st.floats(-28, 28))
def test_mit_roundtrip(q, v, kp, kd, t):
    out = D.decode_mit(D.encode_mit(q, v, kp, kd, t, R4340), R4340)
    steps = (25 / 65535, 16 / 4095, 500 / 4095, 5 / 4095, 56 / 4095)
    for x, y, s in zip((q, v, kp, kd, t), out, steps, strict=True):
        assert x - s - 1e-9 <= y <= x + 1e-9


@given(st.integers(1, 15), st.sampled_from(sorted(D.ERR_FLAGS)), st.floats(-12.5, 12.5), st.floats(-30, 30),
       st.floats(-10, 10), st.integers(0, 255), st.integers(0, 255))
def test_feedback_roundtrip(sid, err, q, v, tau, tm, tr):
    out = D.decode_feedback(D.encode_feedback(sid, err, q, v, tau, tm, tr, R4310), R4310)
    assert out[:2] == (sid, err) and out[5:] == (tm, tr)
    assert abs(out[2] - q) <= 25 / 65535 + 1e-9 and abs(out[3] - v) <= 60 / 4095 + 1e-9
    assert abs(out[4] - tau) <= 20 / 4095 + 1e-9


@settings(max_examples=300)
@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8), st.booleans())
def test_feedback_decoder_never_raises(arb_id, data, expect_regs):
    dec = D.DamiaoFeedbackDecoder([1, 2, 3], [0x11, 0x12, 0x13])
    dec.expect_registers = expect_regs
    dec.push(arb_id, data, 0.0)
    assert dec.counters.ok + dec.counters.rejected == 1


@given(st.binary(min_size=8, max_size=8))
def test_every_8_byte_payload_decodes(d):
    D.decode_feedback(d, R4310), D.decode_mit(d, R4340), D.decode_reg_request(d), D.decode_reg_reply(d, 1)
    D.special_code(d)


def test_feedback_decoder_counts():
    dec = D.DamiaoFeedbackDecoder([1, 2], [0x11, 0x12])
    good = D.encode_feedback(1, 1, 0.1, 0, 0, 30, 30, R4310)
    assert dec.push(0x11, good, 1.0) and dec.t_rx[0] == 1.0
    assert not dec.push(0x12, good, 1.0)  # id nibble 1 on motor 2's feedback id
    assert not dec.push(0x11, good[:6], 1.0)
    assert not dec.push(0x99, good, 1.0)
    assert not dec.push(0x11, good, 1.0, is_ext=True)
    c = dec.counters
    assert (c.ok, c.bad_frame, c.bad_dlc, c.unknown_id) == (1, 2, 1, 1)
