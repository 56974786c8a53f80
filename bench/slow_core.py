"""Run a command on a slowed core (issue #53 item 2): a CPU bandwidth limit through a cgroup, so the timing
benchmarks can be run on this machine as on one whose core is FACTOR times slower.

    python -m bench.slow_core [--factor 2.8] [--period-us 1000] -- factr2 demo --headless --json OUT
    python -m bench.slow_core --factor 2.8 -- python -m pytest -n 0 tests/test_teleop_twin_cli.py -q

The command and every process it starts run in a fresh cgroup that may use each CPU for 1 / FACTOR of every
period: the CFS quota (normal threads) and, on cgroup v1 with RT group scheduling, the real-time budget
(the loop's SCHED_FIFO threads, which a CFS quota does not limit). A 1 ms period makes the limit bite within
a tick, as a slower core does: a tick that needs 0.3 ms of CPU then takes ~0.84 ms of wall time at factor 2.8.
What it does not reproduce: the thread's CPU time per tick (time.thread_time) stays this core's, so the
loop's "CPU per tick" must be multiplied by FACTOR to compare with a slower core's; its wall-clock numbers
(rate, period p99, busy time in a tick) are the slowed core's. The CFS quota is over all the CPUs the
command may use: on 2 CPUs one busy thread may take 2/FACTOR of a CPU, so a single-threaded workload is slowed
FACTOR/2 only; pinned to one CPU (`taskset -c 1 python -m bench.slow_core ...`) every thread shares 1/FACTOR
of it. The kernel's smallest quota is 1 ms: the period grows where FACTOR would ask less (bandwidth()).
Root (or a delegated cgroup) is needed; where none is writable it says so and exits 2. cgroup v2 (cpu.max)
has no real-time budget: the command then runs with FACTR2_NO_RT=1 so that the limit applies to every
thread.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

V1 = Path("/sys/fs/cgroup/cpu")
V2 = Path("/sys/fs/cgroup")
QUOTA_MIN_US = 1000  # the kernel's smallest CFS quota (cfs_quota_us, cpu.max) [us]
RMDIR_TRIES = 50  # 0.1 s apart: how long the group's last processes get to exit after the command


def bandwidth(factor: float, period_us: int, n_cpus: int) -> tuple[int, int]:
    """(period, quota) [us] giving n_cpus / factor CPUs. The period grows where the quota would fall under the
    kernel's 1 ms minimum: clamped instead, factor 2.8 on 2 CPUs at 1 ms asked 714 us and got 1000, a whole
    CPU, and a single thread ran at full speed."""
    quota = period_us * n_cpus / factor
    if quota < QUOTA_MIN_US:
        return int(-(-QUOTA_MIN_US * factor // n_cpus)), QUOTA_MIN_US
    return period_us, int(quota)


def _write(path: Path, value: str) -> None:
    path.write_text(value)


def make_group(name: str, factor: float, period_us: int, n_cpus: int) -> tuple[Path, dict[str, str]]:
    """A cgroup limited to 1/factor of each CPU; returns (its folder, extra environment for the command)."""
    share = 1.0 / factor
    if (V1 / "cpu.cfs_quota_us").exists():
        g = V1 / name
        g.mkdir(exist_ok=True)
        cfs_period, quota = bandwidth(factor, period_us, n_cpus)
        _write(g / "cpu.cfs_period_us", str(cfs_period))
        _write(g / "cpu.cfs_quota_us", str(quota))
        env = {}
        if (g / "cpu.rt_runtime_us").exists():  # per CPU: the loop's FIFO thread gets 1/factor of its core
            _write(g / "cpu.rt_period_us", str(period_us))
            try:
                _write(g / "cpu.rt_runtime_us", str(int(period_us * share)))
            except OSError as e:  # EINVAL: the groups' real-time budgets would exceed their parent's
                g.rmdir()
                raise OSError(f"{e.strerror}: the real-time budgets of the slowed groups already running "
                              f"(factr2-slow-*, 1/{factor:g} each) would exceed the parent's; wait for "
                              "them, or remove the empty ones a killed run left") from None
        else:
            env["FACTR2_NO_RT"] = "1"
        return g, env
    if "cpu" in (V2 / "cgroup.controllers").read_text().split():
        g = V2 / name
        g.mkdir(exist_ok=True)
        cfs_period, quota = bandwidth(factor, period_us, n_cpus)
        _write(g / "cpu.max", f"{quota} {cfs_period}")
        return g, {"FACTR2_NO_RT": "1"}
    raise PermissionError("no cgroup cpu controller here")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--factor", type=float, default=2.8, help="how many times slower the core is (> 1)")
    ap.add_argument("--period-us", type=int, default=1000, help="bandwidth period [us] (1000: within a tick)")
    ap.add_argument("cmd", nargs=argparse.REMAINDER)
    a = ap.parse_args()
    cmd = a.cmd[1:] if a.cmd[:1] == ["--"] else a.cmd
    if not cmd or not a.factor > 1.0 or a.period_us < 1000:
        print("slow_core: give --factor > 1, --period-us >= 1000 and a command after --", file=sys.stderr)
        return 2
    name, n = f"factr2-slow-{os.getpid()}", len(os.sched_getaffinity(0))
    try:
        group, env = make_group(name, a.factor, a.period_us, n)
    except OSError as e:
        print(f"slow_core: cannot make a CPU-limited cgroup ({e}); run as root or in a delegated cgroup",
              file=sys.stderr)
        return 2
    period, quota = bandwidth(a.factor, a.period_us, n)
    print(f"slow_core: {group} limits its threads to {quota} us of CPU time every {period} us ({n} CPU(s) / "
          f"{a.factor:g}; the loop's real-time threads to 1/{a.factor:g} of each CPU)"
          + (" (FACTR2_NO_RT=1: the limit must reach every thread)" if env else ""), file=sys.stderr)
    procs = group / "cgroup.procs"
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # a kill ends the command and the group too
    proc = None
    try:
        proc = subprocess.Popen(cmd, env={**os.environ, **env},
                                preexec_fn=lambda: procs.write_text(str(os.getpid())))
        return proc.wait()
    except KeyboardInterrupt:  # Ctrl-C reaches the command too; SIGTERM (below) only this process
        if proc is not None:
            proc.terminate()
            proc.wait()
        return 130
    finally:
        # a process the command killed as it ended (a busy neighbour: `spin & ...; kill $!`) may still be
        # exiting: a group left behind keeps its real-time budget, and the next run is refused (EINVAL above)
        for _ in range(RMDIR_TRIES):
            try:
                group.rmdir()
                break
            except OSError:
                time.sleep(0.1)
        else:
            print(f"slow_core: {group} still holds a process; remove it (rmdir) once that has ended",
                  file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
