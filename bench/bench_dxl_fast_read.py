"""CPU per DynamixelLeader.read(): Fast Sync Read (0x8A) vs plain sync read, 6 joints + trigger.

SIMULATED chain on the in-process port (hardware/dynamixel/inprocess.py), so one read's CPU is the driver
(dynamixel-sdk + decode) plus the emulator answering; the emulator's share is timed separately.

    python -m bench.bench_dxl_fast_read --reads 2000
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench import harness
from hardware.dynamixel.config import DynamixelLeaderConfig
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.dynamixel.leader import DynamixelLeader
from hardware.sim.motors import IdealMotorBank
from hardware.types import JointLimits

N_JOINTS = 6


def run(fast: bool, reads: int) -> tuple[float, float]:
    """(CPU per read, emulator CPU per read) [us]."""
    ids = list(range(1, N_JOINTS + 2))  # the joints, then the trigger
    bank = IdealMotorBank(N_JOINTS + 1, torque_constant=0.354, q0=np.linspace(-1.0, 1.0, N_JOINTS + 1))
    emu = DynamixelEmulator(bank, ids, "XL330-M288", return_delay=0, emulate_return_delay=False,
                            transport="inprocess", clock=lambda: 0.0)
    serve, emu_cpu = emu.serve, [0.0]

    def timed_serve(data, rate=None):
        t0 = time.process_time()
        try:
            return serve(data, rate)
        finally:
            emu_cpu[0] += time.process_time() - t0

    emu.serve = timed_serve
    n = N_JOINTS
    lim = JointLimits(q_min=np.full(n, -9.0), q_max=np.full(n, 9.0), v_max=np.full(n, 9.0),
                      tau_max=np.full(n, 0.4), tau_rate_max=np.full(n, 1e4))
    cfg = DynamixelLeaderConfig(port=emu.port_path, ids=ids[:-1], signs=[1] * n, offsets_rad=[0.0] * n,
                                gripper_id=ids[-1], loop_hz=10.0, fast_sync_read=fast)
    with emu, DynamixelLeader(cfg, lim) as leader:
        assert leader.fast_read == fast
        emu_cpu[0] = 0.0
        t0 = time.process_time()
        for _ in range(reads):
            leader.read()
        cpu = time.process_time() - t0
        assert leader.lost_reads == 0
    return 1e6 * cpu / reads, 1e6 * emu_cpu[0] / reads


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reads", type=int, default=2000)
    harness.add_quick(ap, "50 reads")
    a = ap.parse_args()
    if a.quick:
        a.reads = 50
    print(harness.machine_line())
    for fast in (False, True, False, True):  # twice each: the second pair shows the spread
        per, emu = run(fast, a.reads)
        print(f"{'fast ' if fast else 'plain'} sync read: {per:6.1f} us CPU per leader.read() "
              f"({emu:5.1f} us of it in the emulator), {a.reads} reads")


if __name__ == "__main__":
    main()
