"""PiperFollower against PiperEmulator on python-can's virtual bus, driven in lockstep with IdealMotorBank.

Each tick: command -> clock.sleep(dt) -> [emulator.poll(), bank.advance(t), emulator.emit(t)] -> read().
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hst

from hardware.can_bus import open_bus
from hardware.clock import LockstepClock
from hardware.errors import DeviceError, DeviceNotFound
from hardware.piper import protocol as P
from hardware.piper.config import PiperFollowerConfig
from hardware.piper.emulator import PiperEmulator
from hardware.piper.follower import PiperFollower, default_limits
from hardware.reasons import kind_of
from hardware.safety import DeviceHold
from hardware.sim.motors import MODE_MIT, MODE_POSITION, IdealMotorBank
from hardware.types import (
    STATUS_ENABLED,
    STATUS_HOLD,
    STATUS_OVERTEMP,
    STATUS_STALE,
    FollowerCommand,
)

DT = 0.002
_chan = itertools.count()
Q0 = np.array([0.1, 0.5, -0.6, 0.2, -0.3, 0.4])


class Rig:
    def __init__(self, mode="position", drop_prob=0.0, old_fw=False, fw_x4=False, q0=Q0, watchdog_s=0.05):
        ch = f"piper-test-{next(_chan)}"
        self.clock = LockstepClock()
        self.bank = IdealMotorBank(7, torque_constant=[*P.EFFORT_PER_AMP, 1.0],
                                   q0=np.append(q0, 0.02), tau_max=30.0)
        self.emu_bus = open_bus(ch, "virtual")
        self.emu = PiperEmulator(self.emu_bus, self.bank, drop_prob=drop_prob, old_firmware_effort=old_fw,
                                 seed=1)
        self.clock.attach(self.step)
        cfg = PiperFollowerConfig(channel=ch, interface="virtual", mode=mode, firmware_effort_x4=fw_x4)
        self.f = PiperFollower(cfg, default_limits(), clock=self.clock, watchdog_s=watchdog_s)

    def step(self, t):
        self.emu.poll()
        self.bank.advance(t)
        self.emu.emit(t)

    def run(self, cmd: FollowerCommand | None, seconds: float):
        st = None
        for _ in range(int(round(seconds / DT))):
            if cmd is not None:
                self.f.command(cmd)
            self.clock.sleep(DT)
            st = self.f.read()
        return st

    def close(self):
        self.f.disconnect()
        self.emu_bus.shutdown()


@pytest.fixture
def rig():
    r = Rig()
    r.f.connect()
    yield r
    r.close()


def test_connect_reads_state_and_holds(rig):
    st = rig.f.read()
    np.testing.assert_allclose(st.q, Q0, atol=2e-5)  # 0.001 deg resolution
    assert np.all(st.status & STATUS_ENABLED)
    assert np.all(st.status & STATUS_HOLD)
    assert rig.emu.enabled.all()
    np.testing.assert_allclose(rig.bank.q_d[:6], Q0, atol=2e-5)  # hold = position mode at the measured pose
    assert np.all(rig.bank.mode[:6] == MODE_POSITION)


def test_position_targets_reach_bank_and_state_decodes(rig):
    target = Q0 + np.array([0.05, -0.05, 0.05, -0.05, 0.05, -0.05])
    st = rig.run(FollowerCommand(q=target, gripper=0.035), 1.0)
    np.testing.assert_allclose(rig.bank.q_d[:6], target, atol=2e-5)
    np.testing.assert_allclose(st.q, rig.bank.q[:6], atol=2e-3)  # feedback lags by at most one 200 Hz frame
    np.testing.assert_allclose(st.q, target, atol=3e-3)
    np.testing.assert_allclose(st.q_cmd, target, atol=1e-12)
    assert not np.any(st.status & (STATUS_HOLD | STATUS_STALE))
    assert abs(st.gripper_pos - 0.035) < 1e-3
    np.testing.assert_allclose(st.temperature, 30.0)


def test_velocity_current_and_torque_signs():
    r = Rig()
    r.f.connect()
    r.bank.tau_external[:6] = [2.0, -2.0, 1.0, -1.0, 0.5, -0.5]  # push the joints; the position loop resists
    st = r.run(FollowerCommand(q=Q0), 0.6)
    bank_tau = r.bank.tau_motor[:6]
    np.testing.assert_allclose(st.tau_m, bank_tau, atol=0.05)
    assert np.all(np.sign(st.tau_m) == -np.sign(r.bank.tau_external[:6]))
    r.bank.tau_external[:] = 0
    r.close()


@pytest.mark.parametrize("fw_x4", [False, True])
def test_old_firmware_effort_x4(fw_x4):
    r = Rig(old_fw=True, fw_x4=fw_x4)
    r.f.connect()
    r.bank.tau_external[:6] = 1.0
    st = r.run(FollowerCommand(q=Q0), 0.6)
    ratio = st.tau_m[:3] / r.bank.tau_motor[:3]
    np.testing.assert_allclose(ratio, 1.0 if fw_x4 else 0.25, rtol=0.05)
    np.testing.assert_allclose(st.tau_m[3:], r.bank.tau_motor[3:6], atol=0.05)
    r.close()


def test_mit_mode_sends_quarter_torque_and_bank_gets_full():
    r = Rig(mode="mit")
    r.f.connect()
    tau = np.array([2.0, -1.0, 0.5, 0.4, -0.4, 0.2])
    kp, kd = np.full(6, 20.0), np.full(6, 1.0)
    for _ in range(200):  # the torque slew limit needs a few ticks
        r.f.command(FollowerCommand(q=Q0, tau_ff=tau, kp=kp, kd=kd))
        r.clock.sleep(DT)
        r.f.read()
    assert np.all(r.bank.mode[:6] == MODE_MIT)
    # wire torque is tau/4 with 8-bit steps of 16/255 N*m, x4 back in the "firmware": error <= 4 * 0.063
    np.testing.assert_allclose(r.bank.tau_ff[:6], tau, atol=0.26)
    np.testing.assert_allclose(r.bank.kp[:6], kp, atol=0.2)
    np.testing.assert_allclose(r.bank.q_d[:6], Q0, atol=5e-4)
    r.f.hold("test")
    r.clock.sleep(DT)
    assert np.all(r.bank.mode[:6] == MODE_POSITION)  # hold = position mode, even in MIT config
    r.close()


def test_out_of_limit_command_never_reaches_bank_outside_limits(rig):
    lim = default_limits()
    wild = np.array([10.0, -10.0, 10.0, -10.0, 10.0, -10.0])
    seen_min, seen_max = np.full(6, np.inf), np.full(6, -np.inf)
    for _ in range(1500):
        rig.f.command(FollowerCommand(q=wild))
        rig.clock.sleep(DT)
        rig.f.read()
        seen_min, seen_max = np.minimum(seen_min, rig.bank.q_d[:6]), np.maximum(seen_max, rig.bank.q_d[:6])
    tol = 1e-5  # 0.001 deg wire rounding
    assert np.all(seen_min >= lim.q_min - tol) and np.all(seen_max <= lim.q_max + tol)
    np.testing.assert_allclose(rig.bank.q_d[:6], np.clip(wild, lim.q_min, lim.q_max), atol=tol)


def test_watchdog_holds_when_commands_stop(rig):
    target = Q0 + 0.02
    rig.run(FollowerCommand(q=target), 0.2)
    assert not rig.f.in_safe_state
    st = rig.run(None, 0.2)  # no commands: the watchdog (50 ms) puts the arm on hold
    assert rig.f.in_safe_state
    assert kind_of(rig.f.safety.last_fault) is DeviceHold.WATCHDOG
    assert np.all(st.status & STATUS_HOLD)
    np.testing.assert_allclose(rig.bank.q_d[:6], st.q, atol=5e-3)


def test_silent_arm_marks_stale_and_goes_safe(rig):
    rig.run(FollowerCommand(q=Q0), 0.1)
    rig.emu.silent = True
    for _ in range(50):
        rig.f.command(FollowerCommand(q=Q0))
        rig.clock.sleep(DT)
        rig.f.read()
    assert rig.f.in_safe_state and rig.f.safety.last_fault.get("stale").kind is DeviceHold.NO_FEEDBACK
    rig.emu.silent = False
    st = rig.run(None, 0.02)
    assert not np.any(st.status & STATUS_STALE)


def test_stale_flag_per_joint(rig):
    rig.run(FollowerCommand(q=Q0), 0.05)
    # stop only the J5/J6 angle frame (0x2A7) by filtering it out of the driver's decoder
    orig = rig.f.decoder.push

    def push(arb_id, data, t, is_ext=False, is_special=False):
        return False if arb_id == P.ID_JOINT_FB[2] else orig(arb_id, data, t, is_ext, is_special)

    orig_frames = rig.f.decoder.push_frames  # a twin's feedback stream: one drain's frames at once

    def push_frames(frames, t):
        orig_frames([f for f in frames if f[0] != P.ID_JOINT_FB[2]], t)

    rig.f.decoder.push = push
    rig.f.decoder.push_frames = push_frames
    st = rig.run(FollowerCommand(q=Q0), 0.06)
    stale = (st.status & STATUS_STALE) != 0
    assert stale.tolist() == [False, False, False, False, True, True]


def test_ten_percent_frame_loss_keeps_tracking():
    r = Rig()
    r.f.connect()
    r.emu.drop_prob = 0.10  # 10 % of frames lost in each direction from here on
    target = Q0 + 0.1
    holds0 = r.f.safety.holds
    ramp = [Q0 + (target - Q0) * min(1.0, k / 100) for k in range(400)]
    for q in ramp:
        r.f.command(FollowerCommand(q=q))
        r.clock.sleep(DT)
        st = r.f.read()
    assert r.emu.dropped > 100
    assert r.f.safety.holds == holds0  # no watchdog trip from 10 % loss
    np.testing.assert_allclose(st.q, target, atol=5e-3)
    r.close()


def test_fault_bits_and_estop_refused():
    r = Rig()
    r.f.connect()
    r.emu.fault_flags[2] = STATUS_OVERTEMP
    st = r.run(FollowerCommand(q=Q0), 0.06)
    assert st.status[2] & STATUS_OVERTEMP and not st.status[1] & STATUS_OVERTEMP
    r.close()
    r2 = Rig()
    r2.emu.arm_status = P.ARM_STATUS_ESTOP
    with pytest.raises(DeviceError, match="emergency stop"):
        r2.f.connect()
    r2.emu_bus.shutdown()


def test_enable_is_repeated_and_refusal_is_reported():
    r = Rig()
    calls = []
    orig = r.emu._on_enable

    def flaky_enable(motor, on):  # the first two enable frames are ignored, like a busy arm
        calls.append(motor)
        if len(calls) > 2:
            orig(motor, on)

    r.emu._on_enable = flaky_enable
    r.f.connect()
    assert len(calls) == 3 and r.emu.enabled.all()
    r.close()
    r2 = Rig()
    r2.emu._on_enable = lambda motor, on: None  # never enables
    with pytest.raises(DeviceError, match=r"joint\(s\) \[1, 2, 3, 4, 5, 6\] did not enable"):
        r2.f.connect()
    assert not r2.f.is_connected
    r2.emu_bus.shutdown()


def test_no_arm_on_channel_is_one_line_error():
    clock = LockstepClock()
    cfg = PiperFollowerConfig(channel="piper-nobody", interface="virtual", connect_timeout_s=0.05)
    f = PiperFollower(cfg, clock=clock)
    with pytest.raises(DeviceNotFound) as e:
        f.connect()
    assert "\n" not in str(e.value) and "no feedback" in str(e.value) and "fix:" in str(e.value)
    assert not f.is_connected


def test_missing_socketcan_channel_is_one_line_error():
    f = PiperFollower(PiperFollowerConfig(channel="can_missing9", interface="socketcan"))
    with pytest.raises(DeviceNotFound) as e:
        f.connect()
    msg = str(e.value)
    assert "\n" not in msg and "can_missing9" in msg and "fix:" in msg


def test_firmware_query(rig):
    assert rig.f.query_firmware() == "S-V1.8-3-SIM"


def test_garbage_on_bus_is_counted_not_raised(rig):
    import can
    junk = [can.Message(arbitration_id=P.ID_JOINT_FB[0], data=b"\x01\x02", is_extended_id=False),
            can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False),
            can.Message(arbitration_id=P.ID_STATUS, data=bytes(8), is_extended_id=True)]
    for m in junk:
        rig.emu_bus.send(m)
    rig.run(FollowerCommand(q=Q0), 0.01)
    c = rig.f.decoder.counters
    assert (c.bad_dlc, c.unknown_id, c.bad_frame) == (1, 1, 1)
    bad_mit = bytearray(P.encode_mit(0, 0, 0, 0, 0))
    bad_mit[7] ^= 0x1
    rig.f.link.send(P.ID_MIT[0], bytes(bad_mit))
    rig.clock.sleep(DT)
    assert rig.emu.decoder.counters.bad_crc == 1


def test_probe_reports_healthy_and_faulty_arm():
    from hardware.can_probe import probe_piper
    r = Rig()
    bus = open_bus(r.f.config.channel, "virtual")
    rep = probe_piper(bus, r.f.config, clock=r.clock)
    assert rep.ok, rep.lines()
    assert rep.firmware == "S-V1.8-3-SIM" and rep.round_trip_ms is not None
    assert 180 <= rep.feedback_hz["joint angles"] <= 220 and 30 <= rep.feedback_hz["low-speed"] <= 50
    assert rep.temperatures_c == [30.0] * 6 and rep.simulated_time
    r.emu.fault_flags[1] = STATUS_OVERTEMP
    r.emu.arm_status = P.ARM_STATUS_COLLISION
    rep = probe_piper(bus, r.f.config, clock=r.clock)
    assert not rep.ok and any("collision" in e for e in rep.errors)
    assert any("joint 2" in e and "overtemperature" in e for e in rep.errors)
    r.emu.silent = True
    rep = probe_piper(bus, r.f.config, clock=r.clock, listen_s=0.05)
    assert not rep.ok and "no feedback" in rep.errors[0]
    bus.shutdown()
    r.emu_bus.shutdown()


def test_end_pose_from_emulator_fk():
    r = Rig()
    r.emu.fk = lambda q: (0.1 + q[0], 0.2, 0.3, q[1], 0.0, -q[2])  # any function of q will do
    r.f.connect()
    st = r.run(FollowerCommand(q=Q0), 0.02)
    pose = r.f.end_pose()
    assert pose == pytest.approx((0.1 + st.q[0], 0.2, 0.3, st.q[1], 0.0, -st.q[2]), abs=1e-4)
    r.close()


@settings(max_examples=15, deadline=None)
@given(hst.lists(hst.floats(-20, 20), min_size=6, max_size=6), hst.sampled_from(["position", "mit"]))
def test_random_commands_never_reach_bank_outside_limits(q_wild, mode):
    r = Rig(mode=mode)
    r.f.connect()
    lim = default_limits()
    for _ in range(60):
        r.f.command(FollowerCommand(q=np.array(q_wild), tau_ff=np.array(q_wild), kp=np.full(6, 1e4)))
        r.clock.sleep(DT)
        r.f.read()
        assert np.all(r.bank.q_d[:6] >= lim.q_min - 1e-4) and np.all(r.bank.q_d[:6] <= lim.q_max + 1e-4)
        assert np.all(np.abs(r.bank.tau_ff[:6]) <= lim.tau_max + 0.26)  # 8-bit MIT torque step x4
        assert np.all(r.bank.kp[:6] <= lim.kp_max + 0.2)
    r.close()
