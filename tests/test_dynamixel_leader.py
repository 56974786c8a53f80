"""DynamixelLeader <-> emulator over a pty through dynamixel-sdk: connect, read, torque, errors, faults."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from hardware.dynamixel import protocol as p
from hardware.dynamixel.config import DynamixelLeaderConfig
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.dynamixel.leader import DynamixelLeader
from hardware.dynamixel.leader_math import (
    torque_to_current_units,
    trigger_fraction,
    wrap_to_offset,
    wrapped_tick_delta,
)
from hardware.errors import DeviceError, DeviceNotFound, UserError
from hardware.sim.motors import MODE_CURRENT, MODE_DISABLED, IdealMotorBank
from hardware.types import STATUS_ENABLED, STATUS_STALE, JointLimits

N = 4
IDS = [1, 2, 3, 4]
SIGNS = [1, -1, 1, -1]
OFFSETS = [0.3, 4.0, -2.5, 7.0]  # assembly offsets beyond +-pi exercise the turn resolution
K = 0.52 / 1.47


def limits(n=N):
    return JointLimits(
        q_min=np.full(n, -10.0),
        q_max=np.full(n, 10.0),
        v_max=np.full(n, 10.0),
        tau_max=np.full(n, 0.4),
        tau_rate_max=np.full(n, 1e4),
    )


def make(q0=(0.2, -0.7, 1.1, -2.0), gripper=False, **emu_kw):
    n_motors = N + (1 if gripper else 0)
    bank = IdealMotorBank(n_motors, torque_constant=K, q0=np.array(list(q0) + ([0.6] if gripper else [])))
    ids = IDS + ([9] if gripper else [])
    emu = DynamixelEmulator(
        bank,
        ids,
        "XL330-M288",
        signs=SIGNS + ([1] if gripper else []),
        offsets_rad=OFFSETS + ([0.0] if gripper else []),
        seed=1,
        **emu_kw,
    )
    cfg = DynamixelLeaderConfig(
        port=emu.port_path,
        ids=IDS,
        signs=SIGNS,
        offsets_rad=OFFSETS,
        gripper_id=9 if gripper else None,
        gripper_open_rad=0.2,
        gripper_closed_rad=1.2,
        rx_timeout_ms=30.0,
        loop_hz=10.0,
    )
    return bank, emu, DynamixelLeader(cfg, limits())


@pytest.fixture
def connected():
    bank, emu, leader = make()
    leader.connect()
    yield bank, emu, leader
    leader.disconnect()
    emu.close()


def test_pure_helpers():
    assert np.allclose(wrap_to_offset([0.1, 6.0], [2 * math.pi, 0.0]), [0.1 + 2 * math.pi, 6.0 - 2 * math.pi])
    assert list(wrapped_tick_delta([10, 4090, 2000], [4090, 10, 0])) == [16, -16, 2000]
    u = torque_to_current_units([0.1, 0.1, 10.0], [1, -1, 1], [0.5, 0.5, 0.5], 0.001, [1750, 1750, 1750])
    assert list(u) == [200, -200, 1750]
    assert math.isclose(trigger_fraction(0.7, 0.2, 1.2), 0.5) and trigger_fraction(5.0, 0.2, 1.2) == 1.0


def test_connect_configures_servos_and_reads_joints(connected):
    bank, emu, leader = connected
    for s in emu.servos:
        assert s.get(p.ADDR_RETURN_DELAY_TIME) == 0 and s.get(p.ADDR_OPERATING_MODE) == p.OP_MODE_CURRENT
        assert s.torque_on
    assert leader.round_trip_s > 0 and not any("timer" in w for w in leader.warnings)
    st = leader.read()
    assert np.allclose(st.q, bank.q, atol=2e-3)  # signs, offsets and turn resolution undone
    assert np.all(st.status & STATUS_ENABLED) and not np.any(st.status & STATUS_STALE)


def test_command_torque_reaches_bank_as_current(connected):
    bank, emu, leader = connected
    tau = np.array([0.1, 0.1, -0.2, 0.05])
    time.sleep(0.002)  # the safety layer's slew limit needs dt > 0 since connect
    sent = leader.command_torque(tau)
    assert np.allclose(sent, tau)
    assert emu.drain(1.0)
    assert np.all(bank.mode == MODE_CURRENT)
    assert np.allclose(bank.current_cmd * K, tau, atol=K * 0.001)  # 1 mA quantisation
    goal = [emu.servo(i).get(p.ADDR_GOAL_CURRENT, signed=True) for i in IDS]
    assert goal == [round(s * t / K / 0.001) for s, t in zip(SIGNS, tau)]
    bank.advance(0.02)
    st = leader.read()
    assert np.allclose(st.tau_m, tau, atol=2 * K * 0.001) and np.allclose(st.current * K, st.tau_m)
    time.sleep(0.002)
    leader.command_torque(np.full(N, 5.0))  # the safety layer clips to tau_max
    emu.drain(1.0)
    assert np.allclose(bank.current_cmd * K, 0.4, atol=K * 0.001)


def test_multi_turn_integration(connected):
    bank, emu, leader = connected
    # joint 0 travels 3.6 rad in steps well under half a turn, each small enough to be a plausible move
    # between two reads (hardware.safety.implausible_jump: a larger step within microseconds is a glitch)
    for _ in range(24):
        bank.q[0] += 0.15
        leader.read()
    assert abs(leader.read().q[0] - bank.q[0]) < 2e-3


def test_gripper_trigger():
    bank, emu, leader = make(gripper=True)
    with emu, leader:
        assert abs(leader.read().gripper_pos - 0.4) < 2e-3  # 0.6 rad between open 0.2 and closed 1.2
        assert not emu.servo(9).torque_on


def test_missing_port_is_one_line():
    cfg = DynamixelLeaderConfig(port="/dev/ttyUSB_nope", ids=IDS, signs=SIGNS, offsets_rad=OFFSETS)
    with pytest.raises(DeviceNotFound) as e:
        DynamixelLeader(cfg, limits()).connect()
    msg = str(e.value)
    assert "/dev/ttyUSB_nope" in msg and "fix:" in msg and "\n" not in msg


def test_wrong_id_lists_answering_ids():
    bank, emu, leader = make()
    leader.config.ids = [1, 2, 3, 7]
    leader.read_ids = [1, 2, 3, 7]
    with emu, pytest.raises(DeviceNotFound) as e:
        leader.connect()
    msg = str(e.value)
    assert "[7]" in msg and "[1, 2, 3, 4]" in msg and "\n" not in msg
    assert not leader.is_connected


def test_wrong_model_is_user_error():
    bank = IdealMotorBank(N, torque_constant=K)
    emu = DynamixelEmulator(bank, IDS, ["XL330-M288", "XL330-M288", "XM430-W350", "XL330-M288"])
    cfg = DynamixelLeaderConfig(port=emu.port_path, ids=IDS, signs=SIGNS, offsets_rad=OFFSETS)
    with emu, pytest.raises(DeviceError) as e:
        DynamixelLeader(cfg, limits()).connect()
    assert "id 3 is XM430-W350" in str(e.value) and isinstance(e.value, UserError)


def test_packet_loss_keeps_working():
    bank, emu, leader = make(drop_prob=0.0)
    with emu, leader:
        emu.drop_prob = 0.05
        fresh = 0
        for k in range(200):
            bank.q[:] = 0.3 * math.sin(0.05 * k)
            st = leader.read()
            fresh += not np.any(st.status & STATUS_STALE)
            leader.command_torque(np.full(N, 0.01))
        assert emu.dropped > 0 and leader.lost_reads > 0
        assert fresh > 150
        emu.drop_prob = 0.0
        assert np.allclose(leader.read().q, bank.q, atol=2e-3)


def test_silent_servo_reads_stale_and_goes_safe():
    bank, emu, leader = make()
    with emu, leader:
        leader.read()
        leader.command_torque(np.full(N, 0.1))
        emu.set_silent(True)
        st = leader.read()
        assert np.all(st.status & STATUS_STALE)
        time.sleep(0.06)  # past the 50 ms watchdog
        leader.read()
        assert leader.in_safe_state
        emu.set_silent(False)
        emu.drain(1.0)
        assert not np.any(leader.read().status & STATUS_STALE)


def test_busy_port_recovered_and_disconnect_frees_servos(connected):
    bank, emu, leader = connected
    leader.bus.port.is_using = True  # what a Ctrl-C inside txRxPacket leaves behind
    assert not np.any(leader.read().status & STATUS_STALE)
    assert leader.bus.busy_recoveries == 1
    leader.disconnect()
    assert np.all(bank.mode == MODE_DISABLED) and not leader.is_connected


def test_without_current_and_latency_timer_warning(monkeypatch):
    import hardware.dynamixel.bus as bus_mod

    monkeypatch.setattr(bus_mod, "read_latency_timer", lambda port: 16)
    bank, emu, leader = make()
    leader.config.read_current = False
    leader.field = (p.FEEDBACK_NO_CURRENT_START, p.FEEDBACK_NO_CURRENT_LEN)
    leader.config.rx_timeout_ms = None  # auto: 2 x 16 ms latency timer + wire time + margin
    with emu, leader:
        assert any("latency timer is 16 ms" in w and "echo 1" in w for w in leader.warnings)
        assert leader.rx_timeout_ms > 32.0
        st = leader.read()
        assert np.allclose(st.q, bank.q, atol=2e-3) and np.all(np.isnan(st.tau_m))


def test_hardware_error_flags_driver_error_and_doctor_names_it():
    from hardware.dynamixel_probe import probe_dynamixel
    from hardware.types import STATUS_DRIVER_ERROR

    bank, emu, leader = make()
    with emu:
        with leader:
            emu.set_hardware_error(3, 1 << 5)  # overload: the servo drops torque
            st = leader.read()
            flagged = (st.status & STATUS_DRIVER_ERROR) != 0
            assert list(flagged) == [False, False, True, False]
            assert bank.mode[2] == MODE_DISABLED
        rep = probe_dynamixel(emu.port_path, 4_000_000, IDS, rounds=3)
        errors = [f for f in rep.findings if f.level == "error"]
        assert any("overload" in f.message and "servo 3" in f.subject for f in errors)
