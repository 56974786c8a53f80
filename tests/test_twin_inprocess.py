"""The lockstep twin's fast paths (SIMULATED): the in-process Dynamixel transport (same sdk bytes as the pty,
deterministic) and the leader worlds' 500 Hz firmware-law rate (motion checked against 1 kHz)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from hardware.connect import open_rig
from hardware.dynamixel.bus import DynamixelBus
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.errors import DeviceNotFound
from hardware.rigs import load_rig
from hardware.sim.twin import Twin
from hardware.types import FollowerCommand

TARGET = np.array([0.3, 0.8, -0.6, 0.1, 0.3, -0.2])


def _leader_run(transport: str, seed: int = 3, steps: int = 120) -> np.ndarray:
    rows = []
    with open_rig("sim-piper", clock="lockstep", seed=seed, dynamixel_transport=transport) as s:
        assert s.rig.leaders[0].config.port.startswith("inproc:" if transport == "inprocess" else "/dev/")
        s.twin.apply_leader_hand_torque(np.array([0.05, 0.0, 0.0, 0.02, 0.0, 0.0]))
        for k in range(steps):
            ls = s.leader.read()
            s.follower.command(FollowerCommand(q=TARGET))
            s.leader.command_torque(0.03 * np.sin(0.05 * k) * np.ones(6))
            s.clock.sleep(0.002)
            rows.append(np.concatenate([ls.q, ls.q_dot, ls.current, [ls.gripper_pos]]))
        assert s.leader.lost_reads == 0 or transport == "pty"
    return np.array(rows)


def test_inprocess_leader_is_bit_identical_per_seed_and_matches_the_pty():
    a, b = _leader_run("inprocess"), _leader_run("inprocess")
    np.testing.assert_array_equal(a, b)
    assert np.ptp(a[:, 0]) > 1e-3  # the leader moved (the hand torque and the commands reach it)
    c = _leader_run("pty")
    # same bytes, same emulator, same physics: the pty run agrees wherever no read was starved by the OS
    assert np.mean(np.all(a == c, axis=1)) > 0.8


def test_inprocess_port_only_exists_in_its_process():
    bus = DynamixelBus("inproc:nobody-serves-this", 4_000_000, where="leader test")
    with pytest.raises(DeviceNotFound, match="in-process"):
        bus.open()


def test_silent_servos_time_out_at_once_in_process():
    from hardware.sim.motors import IdealMotorBank

    emu = DynamixelEmulator(IdealMotorBank(3), [1, 2, 3], return_delay=0, transport="inprocess",
                            emulate_return_delay=False)
    try:
        bus = DynamixelBus(emu.port_path, 4_000_000)
        bus.open()
        assert bus.ping(2) is not None
        assert bus.broadcast_ping() == [1, 2, 3]  # the sdk's timed broadcast read works on it too
        grp = bus.make_sync_read([1, 2, 3], (132, 4))
        assert set(bus.sync_read(grp, [1, 2, 3], 20.0)) == {1, 2, 3}
        emu.silent_ids = {2}
        t0 = time.perf_counter()
        got = bus.sync_read(grp, [1, 2, 3], 20.0)
        assert time.perf_counter() - t0 < 0.015  # nothing more can arrive: no wall-clock wait
        assert 1 in got and 2 not in got
        assert emu.drain(0.0)
        bus.close()
    finally:
        emu.close()
    with pytest.raises(ValueError, match="transport"):
        DynamixelEmulator(IdealMotorBank(1), [1], transport="usb")


def _leader_motion(leader_hz, mode: str, steps: int = 150) -> tuple[np.ndarray, np.ndarray]:
    with Twin(load_rig("sim-piper"), leader_control_hz=leader_hz, dynamixel_transport="inprocess") as tw:
        b = tw.bank("leader")
        q0, _ = b.true_state()
        idx = np.arange(b.n)
        if mode == "position":
            b.command_position(idx, q0 + 0.3)
        else:
            b.command_current(idx, np.full(b.n, 0.1))
        out = []
        for k in range(steps):
            tw.advance(0.002 * (k + 1))
            out.append(b.true_state()[0])
        return np.array(out), q0


@pytest.mark.parametrize("mode,tol", [("position", 0.02), ("current", 0.05)])
def test_leader_law_at_500_hz_moves_like_1_khz(mode, tol):
    ref, q0 = _leader_motion(None, mode)
    fast, _ = _leader_motion(500.0, mode)
    disp = np.abs(ref - q0).max(axis=0)
    moved = disp > 0.05
    assert moved.sum() >= 3
    # a zero-order hold of 2 ms instead of 1 ms: the trajectories differ by a fraction of the motion
    assert np.all(np.abs(fast - ref).max(axis=0)[moved] < tol * disp[moved] + 1e-3)


def test_leader_rate_follows_the_rig_control_rate():
    import dataclasses

    rig = load_rig("sim-piper")
    assert rig.twin.control_hz == 500.0  # the default firmware-law rate (physics 1 kHz)
    with Twin(rig, dynamixel_transport="inprocess") as tw:
        assert tw.leader_every == 1 and tw.substeps == 2
    fast = dataclasses.replace(rig, twin=dataclasses.replace(rig.twin, control_hz=1000.0))
    with Twin(fast, dynamixel_transport="inprocess") as tw:
        assert tw.leader_every == 2
        tw.advance(0.004)
        assert tw.devices["leader"].world.t == pytest.approx(tw.devices["follower"].world.t)
