"""`factr2 teleop` on sim-piper, recording with the rig's camera(s): loop rate, p99 period, the loop thread's
CPU, frames recorded vs expected, dropped samples, stale holds, and whether the recording reads back with
images lined up with the joint states.

    python -m bench.bench_teleop_record [--seconds 30] [--beside none|spin|train:DEMOS] [--json out.json]
    python -m bench.bench_teleop_record --table --seconds 30 --train-demos DEMOS [--json out.json]
    python -m bench.bench_teleop_record --starts 20 [--seconds 2] [--no-record]   # stale holds at start

--beside runs one other process during the measurement: `spin` is `python -c "while True: pass"`, `train:DIR`
is `factr2 train DIR --obs state` (a training of the previous batch while the operator collects the next).
--table runs the three conditions one after the other (issue #37's table). Each measurement runs in a fresh
interpreter, as `factr2 teleop --record` does. Targets: loop >= 500 Hz, p99 period <= 3 ms, loop CPU <= 20 %
of the period, frames >= 99 % of expected, 0 dropped samples, 0 stale holds. SIMULATED (MuJoCo twin in real
time). Frame timing: each frame is stamped with the rig-clock time of the physics state it shows; the error
reported is the distance to the nearest follower joint-state sample.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from argparse import Namespace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"loop >= 500 Hz": lambda r: r["loop_hz"] >= 499.5,
           "p99 <= 3 ms": lambda r: r["period_p99_ms"] <= 3.0,
           "loop CPU <= 20 %": lambda r: r["loop_cpu_share"] <= 0.20,
           "frames >= 99 %": lambda r: bool(r["cameras"]) and all(c["ratio"] >= 0.99
                                                                   for c in r["cameras"].values()),
           "0 dropped samples": lambda r: r["dropped_samples"] == 0,
           "0 stale holds": lambda r: r["stale_holds"] == 0}


def stale_holds(messages) -> list[str]:
    return [text for _t, _who, text in messages if "stale" in text]


def measure(seconds: float, mode: str, out: Path) -> dict:
    """One `factr2 teleop --record` run in this process (the CLI's own execute())."""
    from factr2_teleop.commands.teleop import execute
    from hardware.recording.reader import Recording

    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    res = execute(Namespace(rig="sim-piper", record=str(out), no_cameras=False, mode=mode, checkpoint=None,
                            rate=None, seconds=seconds))
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
                      "frame_period_ms_mean": float(np.mean(dt) * 1e3) if dt.size else None,
                      "frames_after_loop": int((~inside).sum()),
                      "ts_error_ms_median": float(np.median(err) * 1e3),
                      "ts_error_ms_p99": float(np.percentile(err, 99) * 1e3)}
    stale = stale_holds(res["messages"])
    dt_rec = np.diff(t_js)  # the recording's per-tick stamps: whole-run numbers for any code version
    return {"load_before": load0, "seconds": seconds, "mode": mode, "loop_hz": tm.rate_hz,
            "loop_hz_recording": float(1.0 / dt_rec.mean()),
            "period_p99_ms_recording": float(np.percentile(dt_rec, 99) * 1e3),
            "period_p50_ms": tm.period_p50_ms, "period_p99_ms": tm.period_p99_ms,
            "period_max_ms": tm.period_max_ms, "overruns": tm.overruns, "ticks": tm.ticks,
            "loop_cpu_ms": tm.cpu_mean_ms, "loop_cpu_share": tm.cpu_share,
            "dropped_samples": st.dropped_samples, "dropped_frames": st.dropped_frames,
            "messages_written": st.messages_written, "recorder_error": st.error, "cameras": cams,
            "stale_holds": len(stale), "stale_texts": stale[:5], "process_cpu_s": cpu, "wall_s": wall,
            "file": str(res["recording"]), "file_mb": Path(res["recording"]).stat().st_size / 1e6}


TRAIN_THREADS = [0]  # the training beside: torch threads (0: `factr2 train` picks from the load average)


def start_beside(kind: str, tmp: Path) -> subprocess.Popen | None:
    if kind == "none":
        return None
    if kind == "spin":
        cmd = [sys.executable, "-c", "while True: pass"]
    elif kind.startswith("train:"):
        cmd = [sys.executable, "-m", "factr2_teleop.cli", "train", kind[6:], "--obs", "state",
               "--out", str(tmp / f"run-{time.time_ns()}"), "--steps", "100000"]
        if TRAIN_THREADS[0]:  # --train-threads: fixed, so that before / after pairs train alike
            cmd += ["--threads", str(TRAIN_THREADS[0])]
    else:
        raise SystemExit(f"--beside {kind}: use none, spin or train:DEMOS_DIR")
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
    time.sleep(20.0 if kind.startswith("train:") else 2.0)  # a training first loads its recordings
    if p.poll() is not None:
        raise SystemExit(f"the process beside ({' '.join(cmd)}) ended with {p.returncode} before the run")
    return p


def one_condition(seconds: float, mode: str, beside: str) -> dict:
    """A fresh interpreter per measurement (what `factr2 teleop` is)."""
    with tempfile.TemporaryDirectory(prefix="factr2-bench-rec-") as tmp:
        p = start_beside(beside, Path(tmp))
        try:
            j = Path(tmp) / "r.json"
            subprocess.run([sys.executable, __file__, "--seconds", str(seconds), "--mode", mode,
                            "--out", str(Path(tmp) / "rec"), "--json", str(j), "--quiet"], cwd=ROOT,
                           check=False)
            r = json.loads(j.read_text())
        finally:
            if p is not None:
                p.kill()
                p.wait()
    r["beside"] = beside
    return r


def row(r: dict) -> str:
    cams = r["cameras"]
    fr = min((c["ratio"] for c in cams.values()), default=float("nan"))
    return (f"| {r.get('beside', 'none')} | {r['loop_hz']:.1f} Hz | {r['period_p99_ms']:.2f} ms | "
            f"{r['period_max_ms']:.1f} ms | {r['overruns']} / {r['ticks']} | "
            f"{100 * r['loop_cpu_share']:.0f} % "
            f"({r['loop_cpu_ms']:.2f} ms) | {r['dropped_samples']} | {100 * fr:.1f} % | {r['stale_holds']} |")


def starts(n: int, seconds: float, mode: str, record: bool) -> dict:
    """n fresh `factr2 teleop [--record]` starts: stale holds in each."""
    counts, texts = [], []
    for _ in range(n):
        with tempfile.TemporaryDirectory(prefix="factr2-bench-start-") as tmp:
            p = subprocess.run([sys.executable, "-m", "factr2_teleop.cli", "teleop", "--rig", "sim-piper",
                                "--mode", mode, "--seconds", str(seconds)]
                               + (["--record", tmp] if record else []),
                               cwd=ROOT, capture_output=True, text=True)
        stale = [ln for ln in p.stderr.splitlines() if "stale" in ln]
        counts.append(len(stale))
        texts += stale[:2]
    return {"starts": n, "seconds": seconds, "record": record, "stale_holds_per_start": counts,
            "starts_with_stale": sum(c > 0 for c in counts), "texts": texts[:10]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--mode", default="dob")
    ap.add_argument("--out", default=None, help="recording folder (default: a temporary one)")
    ap.add_argument("--beside", default="none", help="none, spin or train:DEMOS_DIR")
    ap.add_argument("--table", action="store_true", help="quiet, spin and train one after the other")
    ap.add_argument("--train-demos", default=None, help="recordings for the training beside (--table)")
    ap.add_argument("--train-threads", type=int, default=0,
                    help="the training's --threads (default: its own choice from the load average)")
    ap.add_argument("--starts", type=int, default=0, help="count stale holds in N teleop starts instead")
    ap.add_argument("--no-record", action="store_true", help="--starts without --record")
    ap.add_argument("--json", default=None)
    ap.add_argument("--quiet", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    TRAIN_THREADS[0] = a.train_threads
    machine = f"{platform.node()} {platform.processor() or platform.machine()}, {os.cpu_count()} cpu"
    if a.starts:
        seconds = a.seconds if a.seconds < 30 else 2.0
        r = dict(starts(a.starts, seconds, a.mode, not a.no_record), machine=machine)
        print(json.dumps(r, indent=1))
        ok = r["starts_with_stale"] == 0
    elif a.table or a.beside != "none":
        kinds = ["none", "spin", f"train:{a.train_demos}"] if a.table else [a.beside]
        if a.table and not a.train_demos:
            raise SystemExit("--table needs --train-demos DIR (recordings for `factr2 train --obs state`)")
        rows = [one_condition(a.seconds, a.mode, k) for k in kinds]
        print("| beside | loop | p99 period | max | overruns | loop CPU | dropped samples | frames | "
              "stale holds |")
        print("|---|---|---|---|---|---|---|---|---|")
        for x in rows:
            print(row(x))
        r = {"machine": machine, "rows": rows, "targets": {x["beside"]: {k: f(x) for k, f in TARGETS.items()}
                                                            for x in rows}}
        ok = all(all(v.values()) for v in r["targets"].values())
        print("SIMULATED twin: " + "; ".join(f"{b}: " + ", ".join(k for k, v in t.items() if not v)
                                              for b, t in r["targets"].items() if not all(t.values()))
              if not ok else "SIMULATED twin: every target met in every condition")
    else:
        out = Path(a.out or tempfile.mkdtemp(prefix="factr2-bench-rec-"))
        r = dict(measure(a.seconds, a.mode, out), machine=machine)
        r["targets"] = {k: f(r) for k, f in TARGETS.items()}
        ok = all(r["targets"].values())
        if not a.quiet:
            print(json.dumps(r, indent=1))
            print("SIMULATED twin: " + ", ".join(f"{k}: {'PASS' if v else 'FAIL'}"
                                                 for k, v in r["targets"].items()))
    if a.json:
        Path(a.json).write_text(json.dumps(r, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
