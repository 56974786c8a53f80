"""The teleop app's instructions per tick under callgrind (issue #53 item 1): the same session as
bench/app_cpu_per_tick.py (sim-piper twin, lockstep, dob, leader emulator in process), with callgrind's
collection on only inside `TeleopLoop._tick_all` and off again inside the emulator's charged blocks
(hardware/sim_cpu.py `simulated`): the app's own part of a tick, counted, not timed -- deterministic and the
same on a loaded machine, where thread CPU time moves 1.5-2x between runs. Needs valgrind and a C compiler
(the two callgrind client requests are built once into a small shared library in a temporary folder).
SIMULATED.

    python -m bench.tick_instructions BEFORE AFTER [--ticks 300]   # checkouts (roots), one after the other
    python -m bench.tick_instructions BEFORE AFTER --part leader.read   # only inside one device method
    python -m bench.tick_instructions ROOT --part leader.read,law.step   # several, one after the other

--part DEVICE.METHOD (leader.read, leader.command_torque, follower.command, ...): collection on only inside
that method of the first pair's device during the counted ticks (still off inside the emulator's blocks):
the instructions a tick of one part. Several parts, comma-separated: counted one after the other in the
same run (`ticks` ticks each, callgrind's counts dumped after each: CALLGRIND_DUMP_STATS_AT).

Each checkout runs under `valgrind --tool=callgrind` (~3 min for 300 ticks on the 2-vCPU dev VM).
"""

from __future__ import annotations

import argparse
import ctypes
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

_C = """#include <valgrind/callgrind.h>
void cg_start(void) { CALLGRIND_START_INSTRUMENTATION; }
void cg_toggle(void) { CALLGRIND_TOGGLE_COLLECT; }
void cg_zero(void) { CALLGRIND_ZERO_STATS; }
void cg_dump(const char *what) { CALLGRIND_DUMP_STATS_AT(what); }
"""


def _library(folder: Path) -> Path:
    src, lib = folder / "cg.c", folder / "cg.so"
    src.write_text(_C)
    subprocess.run(["cc", "-O2", "-shared", "-fPIC", "-o", str(lib), str(src)], check=True)
    return lib


def _run_inside(root: str, ticks: int, lib_path: str, part: str | None = None) -> None:
    """Under callgrind: 20 ticks to warm up, then `ticks` ticks with collection toggled around the app (or
    around one device method: part)."""
    sys.path.insert(0, root)
    import importlib.util

    spec = importlib.util.spec_from_file_location("app_cpu", Path(__file__).with_name("app_cpu_per_tick.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    from hardware import sim_cpu

    lib = ctypes.CDLL(lib_path)
    on = [False]  # collecting now (outside the emulator's blocks)

    class Simulated:  # the emulator's blocks: collection off while they run (they are the servos' work)
        __slots__ = ()

        def __enter__(self):
            if on[0]:
                lib.cg_toggle()
            return self

        def __exit__(self, *exc):
            if on[0]:
                lib.cg_toggle()

    sim_cpu.simulated = Simulated
    s, loop = mod._session("inprocess")
    counting = [False]  # in the counted ticks (part: collection only inside the method)

    def wrap(p: str):
        device, name = p.split(".")
        method = getattr(getattr(loop.pairs[0], device), name)

        def inside(*a, **k):
            if not counting[0]:
                return method(*a, **k)
            on[0] = True
            lib.cg_toggle()
            try:
                return method(*a, **k)
            finally:
                lib.cg_toggle()
                on[0] = False

        setattr(getattr(loop.pairs[0], device), name, inside)
        return lambda: delattr(getattr(loop.pairs[0], device), name)  # the method as it was

    with s:
        for _ in range(20):
            s.clock.sleep(loop.period_s)
            loop._tick_all(s.clock.now())
        lib.cg_start()
        for p in part.split(",") if part else [None]:
            unwrap = wrap(p) if p else None
            lib.cg_zero()
            for _ in range(ticks):
                s.clock.sleep(loop.period_s)
                now = s.clock.now()
                if p:
                    counting[0] = True
                    loop._tick_all(now)
                    counting[0] = False
                    continue
                on[0] = True
                lib.cg_toggle()
                loop._tick_all(now)
                lib.cg_toggle()
                on[0] = False
            lib.cg_dump((p or "tick").encode())
            if unwrap is not None:
                unwrap()


def measure(root: str, ticks: int, lib: Path, out: Path, part: str | None = None) -> dict[str, float]:
    """Instructions per tick of the app's part (or of each device method of part: "leader.read,...") on
    checkout `root`, by what was counted ("tick" or the method)."""
    cmd = ["valgrind", "--tool=callgrind", "--instr-atstart=no", "--collect-atstart=no",
           f"--callgrind-out-file={out}", sys.executable, __file__, "--inside", root, "--ticks", str(ticks),
           "--lib", str(lib)] + (["--part", part] if part else [])
    r = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "FACTR2_NO_RT": "1"})
    if r.returncode != 0 or "Collected :" not in r.stderr:
        raise SystemExit(f"callgrind run on {root} failed ({r.returncode}): {r.stderr.strip()[-400:]}")
    got = {}
    for f in out.parent.glob(f"{out.name}.*"):  # one file per dump: its trigger names what it counted
        text = f.read_text(errors="replace")
        what = re.search(r"^desc: Trigger: Client Request: (.*)$", text, re.M)
        total = re.search(r"^(?:totals|summary): (\d+)", text, re.M)
        if what and total:
            got[what.group(1)] = int(total.group(1)) / ticks
        f.unlink()
    return got


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("roots", nargs="*", help="checkouts to count (default: this one)")
    ap.add_argument("--ticks", type=int, default=300)
    ap.add_argument("--part", help="one method of the first pair's devices, e.g. leader.read")
    ap.add_argument("--inside", help=argparse.SUPPRESS)
    ap.add_argument("--lib", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.inside:
        _run_inside(a.inside, a.ticks, a.lib, a.part)
        return 0
    roots = a.roots or [str(Path(__file__).resolve().parents[1])]
    with tempfile.TemporaryDirectory() as d:
        lib = _library(Path(d))
        got = []
        for i, root in enumerate(roots):
            counts = measure(root, a.ticks, lib, Path(d) / f"callgrind.{i}.out", a.part)
            got.append(counts)
            for what in a.part.split(",") if a.part else ["tick"]:
                n = counts[what]
                where = f"inside {what}" if a.part else "the app's part"
                print(f"{root}: {n / 1e3:.1f} k instructions per tick ({where}, {a.ticks} ticks, in process)",
                      flush=True)
        if len(got) == 2:
            for what in got[0]:
                print(f"after / before{'' if what == 'tick' else ' (' + what + ')'}: "
                      f"{got[1][what] / got[0][what]:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
