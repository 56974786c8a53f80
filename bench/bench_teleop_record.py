"""`factr2 teleop` on sim-piper, recording with the rig's camera(s): loop rate and p99 period, frames
recorded vs expected, dropped samples, and whether the recording reads back with images lined up with the
joint states.

    python bench/bench_teleop_record.py [--seconds 60] [--out DIR] [--json out.json]

Targets (issue: one session layer): loop >= 500 Hz, p99 period <= 4 ms, frames >= 99 % of expected, 0 dropped
samples. SIMULATED (MuJoCo twin in real time). Frame timing: each frame is stamped with the rig-clock time of
the physics state it shows; the error reported is the distance to the nearest follower joint-state sample.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from argparse import Namespace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--mode", default="dob")
    ap.add_argument("--out", default=None, help="recording folder (default: a temporary one)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    from factr2_teleop.commands.teleop import execute
    from hardware.recording.reader import Recording

    out = Path(a.out or tempfile.mkdtemp(prefix="factr2-bench-rec-"))
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    res = execute(Namespace(rig="sim-piper", record=str(out), no_cameras=False, mode=a.mode, checkpoint=None,
                            rate=None, seconds=a.seconds))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    tm, st = res["timing"], res["status"]
    rec = Recording(res["recording"])
    ep = rec.episodes[0]
    t_js = ep.topic("/follower/joint_state").t
    cams = {}
    for name, cs in res["cameras"].items():
        fr = ep.frames(name)
        # frames while the loop ran (the twin keeps stepping until the cameras stop: a few come after)
        inside = (fr.t >= t_js[0]) & (fr.t <= t_js[-1])
        err = np.array([np.nan])
        if inside.any():
            err = np.min(np.abs(t_js[:, None] - fr.t[None, inside]), axis=0)
        dt = np.diff(fr.t)
        cams[name] = {"expected": cs.expected, "captured": cs.captured, "recorded": len(fr),
                      "ratio": len(fr) / max(cs.expected, 1), "dropped": cs.dropped, "failed": cs.failed,
                      "shape": list(fr.rgb(0).shape) if len(fr) else None,
                      "frame_period_ms_mean": float(np.mean(dt) * 1e3) if dt.size else None,
                      "frame_period_ms_max": float(np.max(dt) * 1e3) if dt.size else None,
                      "frames_after_loop": int((~inside).sum()),
                      "ts_error_ms_median": float(np.median(err) * 1e3),
                      "ts_error_ms_p99": float(np.percentile(err, 99) * 1e3),
                      "ts_error_ms_max": float(np.max(err) * 1e3)}
    r = {"machine": f"{platform.node()} {platform.processor() or platform.machine()}, {os.cpu_count()} cpu",
         "load_before": load0, "seconds": a.seconds, "mode": a.mode, "loop_hz": tm.rate_hz,
         "period_p50_ms": tm.period_p50_ms, "period_p99_ms": tm.period_p99_ms,
         "period_max_ms": tm.period_max_ms,
         "overruns": tm.overruns, "ticks": tm.ticks, "dropped_samples": st.dropped_samples,
         "dropped_frames": st.dropped_frames, "messages": st.messages_written, "cameras": cams,
         "process_cpu_s": cpu, "wall_s": wall, "file": str(res["recording"]),
         "file_mb": Path(res["recording"]).stat().st_size / 1e6}
    ok = {"loop >= 500 Hz": tm.rate_hz >= 499.5, "p99 <= 4 ms": tm.period_p99_ms <= 4.0,
          "frames >= 99 %": all(c["ratio"] >= 0.99 for c in cams.values()) and bool(cams),
          "0 dropped samples": st.dropped_samples == 0}
    r["targets"] = ok
    print(json.dumps(r, indent=1))
    print("SIMULATED twin: " + ", ".join(f"{k}: {'PASS' if v else 'FAIL'}" for k, v in ok.items()))
    if a.json:
        Path(a.json).write_text(json.dumps(r, indent=1))
    return 0 if all(ok.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
