"""DamiaoFollower against DamiaoEmulator on python-can's virtual bus, in lockstep with IdealMotorBank."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from hardware.can_bus import open_bus
from hardware.clock import LockstepClock
from hardware.damiao import protocol as D
from hardware.damiao.config import DamiaoFollowerConfig
from hardware.damiao.emulator import DamiaoEmulator
from hardware.damiao.follower import DamiaoFollower
from hardware.errors import DeviceError, DeviceNotFound
from hardware.reasons import kind_of
from hardware.safety import DeviceHold
from hardware.sim.motors import MODE_DISABLED, IdealMotorBank
from hardware.types import (
    STATUS_ENABLED,
    STATUS_HOLD,
    STATUS_OVERTEMP,
    STATUS_STALE,
    FollowerCommand,
    JointLimits,
)

DT = 0.004  # 250 Hz, the vendor's loop
IDS = [1, 2, 3, 4, 5, 6]
MODELS = ["DM4340"] * 3 + ["DM4310"] * 3
Q0 = np.array([0.1, 0.6, 0.5, -0.2, 0.3, -0.4, -1.0])  # last: gripper motor angle [rad]
_chan = itertools.count()


def limits():
    return JointLimits(q_min=np.full(6, -2.0), q_max=np.full(6, 2.0), v_max=np.full(6, 3.0),
                       tau_max=np.array([9.0, 9, 9, 3, 3, 3]), tau_rate_max=np.full(6, 200.0))


class Rig:
    def __init__(self, drop_prob=0.0, gripper=True, ctrl_mode=1, vmax_reg=None, timeout_ms=50.0, **cfg):
        ch = f"damiao-test-{next(_chan)}"
        n = 7 if gripper else 6
        self.clock = LockstepClock()
        self.bank = IdealMotorBank(n, torque_constant=[4.074] * 3 + [0.945] * (n - 3), q0=Q0[:n],
                                   tau_max=30.0, inertia=0.02, damping=0.2)
        self.emu_bus = open_bus(ch, "virtual")
        ids = IDS + [7] if gripper else IDS
        self.emu = DamiaoEmulator(self.emu_bus, self.bank, ids, MODELS + ["DM4310"] * (n - 6),
                                  drop_prob=drop_prob, seed=3, ctrl_mode=ctrl_mode)
        if vmax_reg is not None:
            for regs in self.emu.registers:
                regs[D.RID_VMAX] = vmax_reg
            self.emu.ranges = [D.MotorRanges(r.pmax, vmax_reg, r.tmax) for r in self.emu.ranges]
        self.clock.attach(self.step)
        c = DamiaoFollowerConfig(channel=ch, ids=list(IDS), motor=list(MODELS), interface="virtual",
                                 gripper_id=7 if gripper else None, timeout_ms=timeout_ms, **cfg)
        self.f = DamiaoFollower(c, limits(), clock=self.clock)

    def step(self, t):
        self.emu.poll()
        self.bank.advance(t)
        self.emu.emit(t)

    def run(self, cmd, seconds):
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


def test_connect_reads_registers_sets_timeout_and_damps(rig):
    assert rig.emu.enabled.all()
    assert all(regs[D.RID_TIMEOUT] == 1000 for regs in rig.emu.registers)  # 50 ms / 50 us
    assert rig.f.ranges[0] == D.MotorRanges(12.5, 8.0, 28.0)
    assert rig.f.ranges[3] == D.MotorRanges(12.5, 30.0, 10.0)
    rig.clock.sleep(DT)
    st = rig.f.read()
    np.testing.assert_allclose(st.q, Q0[:6], atol=5e-4)  # 16 bit over 25 rad
    assert np.all(st.status & STATUS_ENABLED) and np.all(st.status & STATUS_HOLD)
    np.testing.assert_allclose(rig.bank.kp, 0.0)  # hold = damping
    assert np.all(rig.bank.kd[:6] > 0.5)


def test_one_mit_frame_and_one_feedback_per_motor_per_tick(rig):
    rig.run(FollowerCommand(q=Q0[:6]), 0.04)
    tx0, rx0 = rig.f.link.tx_frames, rig.f.link.rx_frames
    rig.run(FollowerCommand(q=Q0[:6]), 10 * DT)
    assert rig.f.link.tx_frames - tx0 == 10 * 7
    assert rig.f.link.rx_frames - rx0 == 10 * 7


def test_tracking_gains_torque_and_gripper(rig):
    target = Q0[:6] + 0.1
    tau = np.array([1.0, -1.0, 0.5, 0.2, -0.2, 0.1])
    st = rig.run(FollowerCommand(q=target, tau_ff=tau, gripper=0.04), 1.5)
    np.testing.assert_allclose(rig.bank.q_d[:6], target, atol=5e-4)
    np.testing.assert_allclose(rig.bank.kp[:6], [80, 80, 80, 10, 10, 10], atol=0.2)
    np.testing.assert_allclose(rig.bank.tau_ff[:6], tau, atol=0.02)  # 12 bit over +-28 N*m
    np.testing.assert_allclose(st.q, target, atol=0.03)
    np.testing.assert_allclose(st.tau_m, rig.bank.tau_motor[:6], atol=0.05)
    np.testing.assert_allclose(st.current, st.tau_m / np.array([4.074] * 3 + [0.945] * 3))
    assert abs(rig.bank.q_d[6] - (-1.25)) < 1e-3  # 0.04 m of 0.08 m stroke -> half of -2.5 rad
    assert abs(st.gripper_pos - 0.04) < 2e-3


def test_registers_drive_the_codec():
    r = Rig(vmax_reg=10.0)  # some DM4340 firmwares use VMAX 10, not 8
    r.f.connect()
    assert r.f.ranges[0].vmax == 10.0
    r.bank.q_dot[0] = 9.0
    r.clock.sleep(DT)
    st = r.f.read()
    assert abs(st.q_dot[0] - 9.0) < 0.02  # 9 rad/s would clamp at 8 with the datasheet VMAX
    r.close()


def test_out_of_limit_command_never_reaches_bank_outside_limits(rig):
    wild = np.array([9.0, -9.0, 9.0, -9.0, 9.0, -9.0])
    hi = np.full(6, -np.inf)
    lo = np.full(6, np.inf)
    for _ in range(500):
        rig.f.command(FollowerCommand(q=wild, tau_ff=np.full(6, 50.0), kp=np.full(6, 900.0)))
        rig.clock.sleep(DT)
        rig.f.read()
        hi, lo = np.maximum(hi, rig.bank.q_d[:6]), np.minimum(lo, rig.bank.q_d[:6])
    assert np.all(hi <= 2.0 + 5e-4) and np.all(lo >= -2.0 - 5e-4)
    assert np.all(np.abs(rig.bank.tau_ff[:6]) <= limits().tau_max + 0.02)


def test_watchdog_damps_when_commands_stop(rig):
    rig.run(FollowerCommand(q=Q0[:6] + 0.05), 0.2)
    assert rig.bank.kp[0] > 0
    st = rig.run(None, 0.2)
    assert rig.f.in_safe_state and kind_of(rig.f.safety.last_fault) is DeviceHold.WATCHDOG
    np.testing.assert_allclose(rig.bank.kp, 0.0)
    assert np.all(st.status & STATUS_HOLD) and not np.any(st.status & STATUS_STALE)  # damping keeps feedback


def test_motor_timeout_register_drops_to_damping_without_host():
    r = Rig()
    r.f.connect()
    r.run(FollowerCommand(q=Q0[:6] + 0.05), 0.1)
    r.f.link.close()  # the host vanishes (no hold, no disable)
    r.f.link = None
    for _ in range(30):
        r.clock.sleep(DT)
    assert r.emu.timeouts == 7 and np.all(r.bank.kp == 0.0)
    r.emu_bus.shutdown()


def test_disconnect_damps_then_disables():
    r = Rig()
    r.f.connect()
    r.run(FollowerCommand(q=Q0[:6]), 0.05)
    r.f.disconnect()
    r.clock.sleep(DT)
    assert not r.emu.enabled.any() and np.all(r.bank.mode == MODE_DISABLED)
    r.emu_bus.shutdown()


def test_ten_percent_frame_loss_keeps_tracking():
    r = Rig()
    r.f.connect()
    r.emu.drop_prob = 0.10  # 10 % of frames lost in each direction from here on
    holds0 = r.f.safety.holds
    target = Q0[:6] + 0.1
    for k in range(300):
        q = Q0[:6] + (target - Q0[:6]) * min(1.0, k / 100)
        r.f.command(FollowerCommand(q=q))
        r.clock.sleep(DT)
        st = r.f.read()
    assert r.emu.dropped > 100 and r.f.safety.holds == holds0
    np.testing.assert_allclose(st.q, target, atol=0.03)
    r.close()


def test_err_codes_map_to_status(rig):
    rig.emu.err[2] = D.ERR_COIL_OVERTEMP
    st = rig.run(FollowerCommand(q=Q0[:6]), 2 * DT)
    assert st.status[2] & STATUS_OVERTEMP and not st.status[1] & STATUS_OVERTEMP


def test_motor_error_that_does_not_clear_is_refused():
    r = Rig()
    r.emu.err[2] = D.ERR_OVERLOAD
    orig = r.emu._special
    r.emu._special = lambda k, code: False if code == D.CODE_CLEAR_ERROR else orig(k, code)  # stuck error
    with pytest.raises(DeviceError, match="id 3: overload"):
        r.f.connect()
    assert not r.f.is_connected
    r.emu_bus.shutdown()
    r2 = Rig()
    r2.emu.err[2] = D.ERR_OVERLOAD  # an error the clear-error frame does clear
    r2.f.connect()
    r2.close()


def test_wrong_control_mode_is_refused():
    r = Rig(ctrl_mode=D.CTRL_MODE_POS_VEL)
    with pytest.raises(DeviceError, match="control mode 2"):
        r.f.connect()
    assert not r.f.is_connected
    r.emu_bus.shutdown()


def test_absent_motor_is_one_line_error():
    r = Rig(gripper=False)
    r.f.config.ids[-1] = 9  # no motor 9 on the bus
    r.f = DamiaoFollower(r.f.config, limits(), clock=r.clock)
    with pytest.raises(DeviceNotFound) as e:
        r.f.connect()
    assert "\n" not in str(e.value) and "motor id 9" in str(e.value) and "fix:" in str(e.value)
    r.emu_bus.shutdown()


def test_missing_socketcan_channel_is_one_line_error():
    f = DamiaoFollower(DamiaoFollowerConfig(channel="can_missing7", ids=IDS, motor=MODELS), limits())
    with pytest.raises(DeviceNotFound) as e:
        f.connect()
    assert "\n" not in str(e.value) and "can_missing7" in str(e.value) and "ip link set" in str(e.value)


def test_garbage_is_counted_not_raised(rig):
    import can
    for m in (can.Message(arbitration_id=0x11, data=b"\x11\x00", is_extended_id=False),
              can.Message(arbitration_id=0x55, data=bytes(8), is_extended_id=False),
              can.Message(arbitration_id=0x12, data=bytes(8), is_extended_id=False)):  # wrong id nibble
        rig.emu_bus.send(m)
    rig.run(FollowerCommand(q=Q0[:6]), DT)
    c = rig.f.decoder.counters
    assert (c.bad_dlc, c.unknown_id, c.bad_frame) == (1, 1, 1)
    rig.f.link.send(0x1, b"\x00")
    rig.f.link.send(0x99, bytes(8))
    rig.clock.sleep(DT)
    assert rig.emu.decode_errors == 2


def test_probe_reads_registers_and_errors():
    from hardware.can_probe import probe_damiao
    r = Rig()
    bus = open_bus(r.f.config.channel, "virtual")
    rep = probe_damiao(bus, r.f.config, clock=r.clock)
    assert rep.ok, rep.lines()
    assert "VMAX 8.0" in rep.status["id 1"] and "VMAX 30.0" in rep.status["id 4"]
    assert rep.round_trip_ms is not None and not rep.temperatures_c
    r.emu.err[3] = D.ERR_UNDERVOLTAGE
    r.emu.registers[5][D.RID_CTRL_MODE] = D.CTRL_MODE_VEL
    rep = probe_damiao(bus, r.f.config, clock=r.clock, with_feedback=True)
    assert not rep.ok and len(rep.temperatures_c) == 7
    assert any("id 4: undervoltage" in e for e in rep.errors) and any("id 6 in control mode 3" in e
                                                                       for e in rep.errors)
    r.emu.silent = True
    rep = probe_damiao(bus, r.f.config, clock=r.clock)
    assert not rep.ok and "does not answer" in rep.errors[0]
    bus.shutdown()
    r.emu_bus.shutdown()


def test_silent_motor_is_stale_and_trips_watchdog(rig):
    rig.run(FollowerCommand(q=Q0[:6]), 0.02)
    orig = rig.emu._send
    rig.emu._send = lambda arb_id, data: None if arb_id == 0x12 else orig(arb_id, data)  # motor 2 goes quiet
    for _ in range(8):  # 32 ms of silence: below the 50 ms watchdog, not stale yet
        rig.f.command(FollowerCommand(q=Q0[:6]))
        rig.clock.sleep(DT)
        st = rig.f.read()
    assert not rig.f.in_safe_state and not np.any(st.status & STATUS_STALE)
    st = rig.run(FollowerCommand(q=Q0[:6]), 0.04)
    assert rig.f.in_safe_state and rig.f.safety.last_fault.get("stale").kind is DeviceHold.NO_FEEDBACK
    assert (st.status & STATUS_STALE).astype(bool).tolist() == [False, True, False, False, False, False]
