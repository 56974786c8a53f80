"""SIMULATED: a lockstep run is the same whatever the machine's speed (issue #24 item 4).

One short scenario on the sim-piper twin (real drivers, CAN and Dynamixel emulators, a push and a virtual
hand) runs twice: as fast as the CPU goes, and with a client slowed down by sleeps in its command path
(a command observer that sleeps, as a slow machine or a busy one would). Every recorded array -- the
drivers' states, what went on the wire, the physics' ground truth, the CAN frames' timestamps and the
servos' Realtime Tick -- must be bit for bit the same. Any wall-clock read on the lockstep path breaks it.
"""

from __future__ import annotations

import time

import can
import numpy as np

from hardware.connect import open_rig
from hardware.dynamixel import protocol as p
from hardware.types import FollowerCommand

RATE_HZ = 500.0
SECONDS = 0.6
SLOW_S = 0.001  # s of wall time the slowed client loses per command (x2 per tick)


def _scenario(slow: bool) -> dict[str, np.ndarray]:
    with open_rig("sim-piper", clock="lockstep", seed=3) as s:
        lead, fol, twin = s.leader, s.follower, s.twin
        tap = can.Bus(interface="virtual", channel=twin.can_channels["follower"])  # sees every frame
        wire: list[np.ndarray] = []
        fol.add_command_observer(lambda t, t_sent, safe: wire.append(np.r_[t, t_sent, safe.q, safe.hold]))
        lead.add_command_observer(lambda t, t_sent, safe: wire.append(np.r_[t, t_sent, safe.tau, -1.0]))
        if slow:
            for d in (lead, fol):
                d.add_command_observer(lambda *a: time.sleep(SLOW_S))
        rows, q0 = [], fol.read().q.copy()
        for k in range(round(SECONDS * RATE_HZ)):
            t = s.clock.now()
            ls, fs = lead.read(), fol.read()
            if k == round(0.2 * RATE_HZ):
                twin.push("link6", np.array([0.0, 20.0, -20.0]), 0.2)
            twin.apply_leader_hand_torque(0.2 * np.sin(2 * np.pi * 1.5 * t + np.arange(6)))
            fol.command(FollowerCommand(q=q0 + 0.2 * np.sin(2 * np.pi * t) * np.r_[1, 0.5, -0.5, 0, 0.3, 0]))
            lead.command_torque(np.clip(0.05 * (fs.q - ls.q), -0.3, 0.3))
            gt = twin.device_ground_truth("follower")
            rows.append(np.r_[t, ls.q, ls.q_dot, ls.current, fs.q, fs.q_dot, fs.tau_m, fs.current,
                              gt.q[:6], gt.tau_ext[:6]])
            s.clock.sleep(1.0 / RATE_HZ)
        stamps = []
        while (msg := tap.recv(0)) is not None:
            stamps.append((msg.timestamp, msg.arbitration_id))
        tap.shutdown()
        emu = twin.devices["leader"].emulator
        a = p.ADDR_REALTIME_TICK[0]
        tick = int.from_bytes(emu.servos[0].table[a:a + 2], "little")  # ms of the rig clock
        return {"rows": np.array(rows), "wire": np.array(wire), "frames": np.array(stamps),
                "tick": np.array([tick, emu.instructions])}


def test_a_slowed_client_records_bit_identical_arrays():
    fast = _scenario(slow=False)
    t0 = time.perf_counter()
    slowed = _scenario(slow=True)
    assert time.perf_counter() - t0 >= 2 * SECONDS * RATE_HZ * SLOW_S  # every command really slept
    assert len(fast["frames"]) > 1000 and np.ptp(fast["frames"][:, 0]) > 0.9 * SECONDS  # rig-clock stamps
    assert np.abs(fast["rows"][:, -6:]).max() > 1.0  # the push really loaded the arm (tau_ext) [N*m]
    for k, a in fast.items():
        b = slowed[k]
        assert a.shape == b.shape and a.dtype == b.dtype, k
        assert a.tobytes() == b.tobytes(), f"{k}: {np.argwhere(a != b)[:3]}"
