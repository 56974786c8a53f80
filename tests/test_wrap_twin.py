"""SIMULATED, lockstep, sim-piper twin (issue #53): the GELLO's wrist roll driven across its servo's wrap
point both ways during teleop, a reading that comes back a whole turn off after a silent chain, and a
restart in another turn. The hand here is a test's impedance on the twin's true joints (what a hand on the
arm feels)."""

from __future__ import annotations

import math

import numpy as np

from factr2_teleop.session.pairs import TeleopOptions
from factr2_teleop.session.teleop import TeleopSession
from factr2_teleop.teleop.pair import COUPLED
from hardware.connect import open_rig
from hardware.dynamixel.leader import DynamixelLeader
from hardware.rigs.rig import rig_path

RATE_HZ = 250.0
WRIST = 5  # the GELLO's wrist roll (j6), limits +-2.09 rad
OFFSETS = "offsets_rad = [3.14159265, 3.14159265, 3.14159265, 3.14159265, 3.14159265, 3.14159265]"


def _rig(tmp_path, wrist_offset_rad: float):
    """sim-piper with the wrist servo mounted at `wrist_offset_rad` (0: its count crosses tick 0 / 4096 at
    the joint's zero, inside the joint's range)."""
    text = rig_path("sim-piper").read_text()
    assert OFFSETS in text
    offsets = [math.pi] * 5 + [wrist_offset_rad]
    path = tmp_path / "sim-piper-wrap.toml"
    path.write_text(text.replace(OFFSETS, f"offsets_rad = {offsets}"))
    return path


class _Run:
    """A lockstep teleop pair (no feedback) and a hand: the start pose on every joint, the wrist at a
    target."""

    def __init__(self, s):
        self.s = s
        self.ts = TeleopSession(s, TeleopOptions(mode="none", rate_hz=RATE_HZ))
        self.pair = self.ts.pairs[0]
        self.leader = self.pair.leader
        self.bank = s.twin.bank(s.rig.leaders[0].name)
        self.emu = s.twin.devices[s.rig.leaders[0].name].emulator
        self.pair.begin(s.clock)
        self.q_home = self.bank.true_state()[0][:6].copy()
        self.phases, self.err = [], []  # per tick: phase; |leader reading - true| on the wrist [rad]

    def hand(self, wrist: float) -> None:
        q, qd = (a[:6] for a in self.bank.true_state())
        ref = self.q_home.copy()
        ref[WRIST] = wrist
        k = np.full(6, 3.0)
        k[WRIST] = 10.0  # N*m/rad: fingers turning the wrist
        self.s.twin.apply_leader_hand_torque(np.clip(k * (ref - q) - 0.1 * qd, -2.0, 2.0))

    def move(self, wrist_from: float, wrist_to: float, seconds: float) -> None:
        n = int(seconds * RATE_HZ)
        for k in range(n):
            s = min(1.0, (k + 1) / (0.7 * n))
            self.hand(wrist_from + (wrist_to - wrist_from) * s * s * (3 - 2 * s))
            self.s.clock.sleep(1 / RATE_HZ)
            rec = self.pair.tick(self.s.clock.now())
            self.phases.append(rec.phase)
            if not self.emu.silent_ids:
                self.err.append(abs(rec.leader.q[WRIST] - self.bank.true_state()[0][WRIST]))

    def wrist(self) -> tuple[float, float, float]:
        """Leader reading, twin's true leader wrist, follower reading [rad]."""
        return (float(self.leader.read().q[WRIST]), float(self.bank.true_state()[0][WRIST]),
                float(self.pair.follower.read().q[WRIST]))


def test_wrist_roll_across_the_wrap_point_both_ways_during_teleop_then_a_restart_in_another_turn(tmp_path):
    with open_rig(_rig(tmp_path, 0.0), clock="lockstep", seed=0) as s:
        r = _Run(s)
        r.move(0.0, 0.0, 1.5)  # soft start
        r.move(0.0, 1.6, 2.0)  # up across the servo's tick 0 / 4096
        r.move(1.6, -1.6, 3.0)  # and down across it again
        r.move(-1.6, -0.8, 2.5)
        assert all(p == COUPLED for p in r.phases[int(1.5 * RATE_HZ):]), set(r.phases)
        assert r.leader.safety.jumps_rejected == 0 and r.leader.turns_unwrapped == 0
        assert max(r.err) < 0.01  # the reading is the arm, to a few encoder ticks
        lead, true, fol = r.wrist()
        assert abs(lead - true) < 0.01 and abs(fol - lead) < 0.1

        # restart: the servos power up again (their count restarts within [0, 4096): the wrist, powered on
        # at or above its tick 0 and now below it, counts from another turn) and the stored offsets are
        # written on another turn
        wrist_servo = r.emu.servos[WRIST]
        before = wrist_servo.servo_ticks(0)
        r.leader.disconnect()
        for servo in r.emu.servos:
            servo.turn_base = None
        r.leader.offsets = r.leader.offsets + 2 * math.pi
        r.leader._q_ok = None  # a new process has accepted nothing yet
        r.leader.connect()
        assert abs(wrist_servo.servo_ticks(0) - before) == 4096  # really another turn
        lead, true, _ = r.wrist()
        assert abs(lead - true) < 0.01
        r.pair.begin(s.clock)  # no "differ too much": the same pose
        r.phases.clear()
        r.move(-0.8, -0.8, 1.0)  # the soft start brings the follower over
        r.move(-0.8, 0.5, 2.0)  # and up across the wrap point on the new turn
        r.move(0.5, 0.5, 0.5)
        # (a reconnect leaves the wrist without torque a moment: it falls fast enough for the plausibility
        # filter to hold a sample or two; that is motion, not a turn)
        assert r.phases[-1] == COUPLED and r.leader.turns_unwrapped == 0
        assert not any("differ too much" in m for m in r.pair.messages)
        lead, true, fol = r.wrist()
        assert abs(lead - true) < 0.01 and abs(fol - lead) < 0.1


def test_a_reading_a_turn_off_after_a_silent_chain_is_put_back_and_the_pair_re_couples(tmp_path, monkeypatch):
    """The chain is silent while the hand turns the wrist 3.7 rad (more than half a turn): the driver's tick
    integrator comes back a whole turn off. Unwrapped, the reading is the arm; the follower held at -1.8 rad,
    so the resume waits until the hand brings the leader back, then the pair re-couples. Without the wrap
    period the same run reads the wrist 2 pi off, as the demo of #53 did."""
    for wraps in (True, False):
        if not wraps:
            monkeypatch.setattr(DynamixelLeader, "wrap_period_rad", math.inf)
        with open_rig(_rig(tmp_path, math.pi), clock="lockstep", seed=0) as s:
            r = _Run(s)
            r.move(0.0, 0.0, 1.0)
            r.move(0.0, -1.8, 1.5)
            assert r.phases[-1] == COUPLED
            r.emu.set_silent(True)
            r.move(-1.8, 1.9, 2.0)  # silent: the follower holds, the hand turns the wrist 3.7 rad
            r.emu.set_silent(False)
            r.move(1.9, 1.9, 0.2)
            lead, true, fol = r.wrist()
            if not wraps:
                assert abs(lead - true + 2 * math.pi) < 0.02  # the failure: a whole turn off
                continue
            assert abs(lead - true) < 0.01 and r.leader.turns_unwrapped >= 1
            assert r.leader.safety.jumps_rejected == 0
            r.move(1.9, -1.8, 2.5)  # the hand brings the leader back to the held follower
            r.move(-1.8, -1.8, 0.5)
            assert r.phases[-1] == COUPLED
            said = " | ".join(r.pair.messages)
            assert "whole turn off" in said and "6.2" not in said, said
