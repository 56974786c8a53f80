"""CAN follower benchmarks: codec frames/s (Piper, Damiao) and end-to-end driver <-> emulator over
python-can's in-process virtual bus, in lockstep with IdealMotorBank (SIMULATED arms).

    python -m bench.bench_can [--seconds 2.0] [--quick]

Codec numbers are single-core Python frames/s. End-to-end: a follower loop (Piper at 1 kHz, Damiao at
250 Hz: command, clock.sleep -> emulator.poll, bank.advance, emulator.emit, read) for `seconds` of simulated
time; prints frames/s over the wire (both directions) and the real-time factor (simulated s / wall s), with
and without the plant (IdealMotorBank.advance) time. Timings on a shared machine are noisy.
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np

from bench import harness
from hardware.can_bus import open_bus
from hardware.clock import LockstepClock
from hardware.damiao import protocol as D
from hardware.damiao.config import DamiaoFollowerConfig
from hardware.damiao.emulator import DamiaoEmulator
from hardware.damiao.follower import DamiaoFollower
from hardware.piper import protocol as P
from hardware.piper.config import PiperFollowerConfig
from hardware.piper.emulator import PiperEmulator
from hardware.piper.follower import PiperFollower
from hardware.sim.motors import IdealMotorBank
from hardware.types import FollowerCommand

_chan = itertools.count()


def rate(fn, frames_per_call: int, seconds: float) -> float:
    """Frames per second of fn() over about `seconds` of wall time."""
    n, t0 = 0, time.perf_counter()
    while True:
        for _ in range(200):
            fn()
        n += 200
        dt = time.perf_counter() - t0
        if dt >= seconds:
            return n * frames_per_call / dt


def bench_codecs(seconds: float) -> None:
    q = [0.1, 0.5, -0.6, 0.2, -0.3, 0.4]
    mit = P.encode_mit(0.1, 0.2, 10, 1, 0.5)
    hs, ls = P.encode_high_speed(1.0, -2.0, 0.3), P.encode_low_speed(24, 30, 31, 0x40, 1.0)
    jf = P.encode_joint_pair(0.1, 0.2)
    r = D.MODELS["DM4340"].ranges
    dfb = D.encode_feedback(1, 1, 0.1, 0.2, 0.3, 30, 31, r)
    dec = P.PiperFeedbackDecoder()
    rows = [
        ("piper encode joint targets (3 frames)", lambda: P.encode_joint_targets(q), 3),
        ("piper encode MIT", lambda: P.encode_mit(0.1, 0.2, 10.0, 1.0, 0.5), 1),
        ("piper encode high-speed feedback", lambda: P.encode_high_speed(1.0, -2.0, 0.3), 1),
        ("piper decode MIT (+crc)", lambda: (P.mit_crc_ok(mit), P.decode_mit(mit)), 1),
        ("piper decode joint angles", lambda: P.decode_joint_pair(jf), 1),
        ("piper decode high-speed", lambda: P.decode_high_speed(hs), 1),
        ("piper decode low-speed (+flags)", lambda: P.low_speed_flags(P.decode_low_speed(ls)[3]), 1),
        ("piper feedback push (validate, keep latest)", lambda: dec.push(0x251, hs, 0.0), 1),
        ("damiao encode MIT", lambda: D.encode_mit(0.1, 0.2, 10.0, 1.0, 0.5, r), 1),
        ("damiao decode feedback", lambda: D.decode_feedback(dfb, r), 1),
    ]
    print("\ncodec (frames/s, one core)")
    for name, fn, k in rows:
        print(f"  {name:46s} {rate(fn, k, seconds):12,.0f}")


def piper_rig(mode: str):
    ch = f"bench-piper-{next(_chan)}"
    clock = LockstepClock()
    bank = IdealMotorBank(7, torque_constant=[*P.EFFORT_PER_AMP, 1.0],
                          q0=[0.1, 0.5, -0.6, 0.2, -0.3, 0.4, 0.02])
    emu_bus = open_bus(ch, "virtual")
    emu = PiperEmulator(emu_bus, bank)
    f = PiperFollower(PiperFollowerConfig(channel=ch, interface="virtual", mode=mode), clock=clock)
    return clock, bank, emu, emu_bus, f


def damiao_rig():
    ch = f"bench-damiao-{next(_chan)}"
    clock = LockstepClock()
    models = ["DM4340"] * 3 + ["DM4310"] * 4
    bank = IdealMotorBank(7, torque_constant=[4.074] * 3 + [0.945] * 4,
                          q0=[0.1, 0.6, 0.5, -0.2, 0.3, -0.4, -1])
    emu_bus = open_bus(ch, "virtual")
    emu = DamiaoEmulator(emu_bus, bank, [1, 2, 3, 4, 5, 6, 7], models)
    cfg = DamiaoFollowerConfig(channel=ch, ids=[1, 2, 3, 4, 5, 6], motor=models[:6], interface="virtual")
    return clock, bank, emu, emu_bus, DamiaoFollower(cfg, clock=clock)


def run_e2e(name: str, rig, dt: float, sim_seconds: float) -> None:
    clock, bank, emu, emu_bus, f = rig
    acc = dict(emulator=0.0, plant=0.0, command=0.0, read=0.0)
    pc = time.perf_counter

    def step(t):
        t0 = pc()
        emu.poll()
        t1 = pc()
        bank.advance(t)
        t2 = pc()
        emu.emit(t)
        acc["emulator"] += (t1 - t0) + (pc() - t2)
        acc["plant"] += t2 - t1

    clock.attach(step)
    f.connect()
    q0 = f.read().q.copy()
    tx0, rx0 = f.link.tx_frames, f.link.rx_frames
    acc.update(emulator=0.0, plant=0.0)
    n = int(round(sim_seconds / dt))
    w0 = pc()
    for k in range(n):
        t0 = pc()
        f.command(FollowerCommand(q=q0 + 0.05 * np.sin(2 * np.pi * 0.5 * k * dt), gripper=0.02))
        t1 = pc()
        clock.sleep(dt)
        t2 = pc()
        f.read()
        acc["command"] += t1 - t0
        acc["read"] += pc() - t2
    wall = pc() - w0
    frames = (f.link.tx_frames - tx0) + (f.link.rx_frames - rx0)
    print(f"  {name:28s} {frames / wall:9,.0f} frames/s wall ({frames / sim_seconds:5,.0f} per sim s), "
          f"real-time x{sim_seconds / wall:5.1f} (without plant x{sim_seconds / (wall - acc['plant']):5.1f})")
    print("      us per tick: " + ", ".join(f"{k} {1e6 * v / n:.0f}" for k, v in acc.items())
          + " (command = safety layer + encode + send; read = drain + decode)")
    f.disconnect()
    emu_bus.shutdown()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per end-to-end run")
    ap.add_argument("--quick", action="store_true", help="short runs (checks the script works)")
    a = ap.parse_args(argv)
    codec_s, sim_s = (0.1, 0.3) if a.quick else (0.5, a.seconds)
    import can

    print(f"{harness.machine_line()}, python-can {can.__version__}")
    print("timings on a shared machine are noisy; SIMULATED arms (emulators + IdealMotorBank)")
    bench_codecs(codec_s)
    print("\nend to end, lockstep over the in-process virtual bus (FastVirtualBus)")
    run_e2e("piper position @1 kHz", piper_rig("position"), 1e-3, sim_s)
    run_e2e("piper position @200 Hz", piper_rig("position"), 5e-3, sim_s)
    run_e2e("piper MIT @1 kHz", piper_rig("mit"), 1e-3, sim_s)
    run_e2e("damiao YAM+gripper @250 Hz", damiao_rig(), 4e-3, sim_s)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
