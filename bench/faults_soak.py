"""The fault soak (issue #35 item 4, SIMULATED): `factr2 teleop --record` in real time on the sim-piper twin
for minutes, seeded random faults, one CPU-bound process beside it. Reports the loop's rate and period p99
outside the faults (from the recording: one follower sample per tick), RSS at start and end, and whether
every recorded file opens.

    python -m bench.faults_soak --minutes 30 --seed 0 --out /tmp/soak --json /tmp/soak.json
    python -m bench.faults_soak --minutes 1 --out /tmp/soak1 --json /tmp/soak1.json     # a quick check

Faults: the device, camera and wall-clock kinds (disk_full needs a small filesystem, next_killed mode next,
the signal kinds end the run: the campaign and the tests play those), FAULTS_PER_MIN a minute, at least GAP_S
apart. "Outside the faults": ticks not within [start - 0.05 s, end + SETTLE_S] of any fault.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np

from bench import harness

ROOT = Path(__file__).resolve().parents[1]

SOAK_KINDS = ("can_loss", "can_busoff", "motor_overcurrent", "motor_overtemp", "motor_encoder", "dxl_unplug",
              "dxl_overload", "dxl_corrupt", "spike_leader", "spike_follower", "camera_freeze", "camera_gone",
              "wall_step_fwd", "wall_step_back")
FAULTS_PER_MIN = 2.0
GAP_S = 5.0  # s between faults
SETTLE_S = 1.5  # s after a fault's end still counted as the fault (soft start, a servo's reboot)
RSS_EVERY_S = 10.0


def _rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def outside_faults(t: np.ndarray, windows: list[tuple[float, float]]) -> np.ndarray:
    """Mask of the tick times t [s] outside every (start, end) window [s] (pure)."""
    keep = np.ones(len(t), bool)
    for a, b in windows:
        keep &= ~((t >= a - 0.05) & (t <= b + SETTLE_S))
    return keep


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, help="recording folder")
    ap.add_argument("--json", required=True)
    ap.add_argument("--no-hog", action="store_true", help="without the CPU-bound process beside it")
    a = ap.parse_args(argv)
    from factr2_teleop.cli import build_parser
    from factr2_teleop.commands import teleop
    from hardware.sim.faults import random_schedule

    seconds = 60.0 * a.minutes
    n = max(1, int(round(FAULTS_PER_MIN * a.minutes)))
    specs = random_schedule(a.seed, list(SOAK_KINDS), n, 5.0, seconds - 5.0, gap_s=GAP_S)
    args = build_parser().parse_args(["teleop", "--rig", "sim-piper", "--record", a.out, "--seconds",
                                      str(seconds)] + [x for s in specs for x in ("--twin-fault", s.text())])
    hog = None if a.no_hog else subprocess.Popen([sys.executable, "-c", "while True: pass"])
    rss, stop = [(0.0, _rss_mib())], threading.Event()

    def sample():
        t0 = time.monotonic()
        while not stop.wait(RSS_EVERY_S):
            rss.append((time.monotonic() - t0, _rss_mib()))

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    t0 = time.perf_counter()
    try:
        out = teleop.execute(args)
    finally:
        stop.set()
        if hog is not None:
            hog.kill()
    rss.append((time.perf_counter() - t0, _rss_mib()))
    from hardware.recording.reader import Recording

    files, opens = sorted(Path(a.out).glob("*.mcap")), []
    for f in files:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                Recording(f, use_cache=False, write_cache=False).topic("/follower/joint_state")
            opens.append(True)
        except Exception:  # noqa: BLE001 -- counted
            opens.append(False)
    off = out["twin_t_offset_s"] or 0.0
    log = out["faults"]
    starts = [e for e in log if e["event"] == "start"]
    windows = []
    for e in starts:
        end = next((x["t_s"] for x in log if x["event"] == "end" and x["kind"] == e["kind"]
                    and x["t_s"] >= e["t_s"]), e["t_s"])
        windows.append((e["t_s"] + off, end + off))
    res = {"simulated": True, "minutes": a.minutes, "seed": a.seed, "hog": not a.no_hog,
           "faults_scheduled": len(specs), "faults_injected": len(starts), "files": len(files),
           "files_open": int(sum(opens)), "rss_mib_before": rss[0][1],
           "rss_mib_start": rss[1][1] if len(rss) > 2 else None,  # the first sample with the session running
           "rss_mib_end": rss[-1][1],
           "rss_mib": rss, "timing_all": out["timing"].line(), "messages": len(out["messages"])}
    if out["recording"] is not None and opens and opens[0]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = Recording(out["recording"], use_cache=False, write_cache=False)
            t = rec.topic("/follower/joint_state").t
        keep = outside_faults(t[1:], windows)
        dt = np.diff(t)[keep]
        res.update(ticks=int(len(t)), ticks_outside=int(keep.sum()),
                   rate_hz_outside=float(1.0 / dt.mean()) if len(dt) else None,
                   period_p99_ms_outside=float(np.percentile(dt, 99) * 1e3) if len(dt) else None,
                   period_max_ms_outside=float(dt.max() * 1e3) if len(dt) else None)
    harness.write(a.json, harness.record(Path(a.json).stem, res, simulated=True))
    print(json.dumps({k: v for k, v in res.items() if k != "rss_mib"}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
