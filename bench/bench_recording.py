"""Recording benchmark: sustained 4 cameras (640x480, 30 Hz) + a 1 kHz control loop, then reading speed.

The control loop logs per tick what a teleop session logs: leader and follower joint states (7 joints),
estimated external torque + contact, the leader's commanded torque and loop timing. Camera frames are
SYNTHETIC (a textured, moving pattern with sensor noise, precomputed so that making them costs nothing);
JPEG cost depends on content, so real cameras may differ. CPU use comes from resource.getrusage.

    python -m bench.bench_recording --seconds 60      # writes bench/out/recording.json
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from bench import harness
from hardware.recording import Recorder, Recording
from hardware.recording.cache import cache_dir
from hardware.types import STATUS_ENABLED, JointState

N_JOINTS = 7


def synthetic_frames(n: int, seed: int, h: int = 480, w: int = 640) -> list[np.ndarray]:
    """n frames of a moving textured scene (gradients, shapes, mild noise) -- not camera footage."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    base = np.stack([x / w * 200, y / h * 180, (x + y) / (w + h) * 160], -1)
    frames = []
    for i in range(n):
        img = base.copy()
        cx, cy = w / 2 + 150 * np.cos(i / n * 2 * np.pi + seed), h / 2 + 100 * np.sin(i / n * 2 * np.pi)
        img[(x - cx) ** 2 + (y - cy) ** 2 < 60 ** 2] = (220, 40, 40)
        img[((x // 40 + y // 40) % 2 == 0) & (y > 380)] *= 0.5  # a checkered table edge
        img += rng.normal(0, 4, img.shape)
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    return frames


def loop_baseline(seconds: float) -> list[float]:
    """Lateness [ms] p50/p99/max of the same 1 kHz sleep loop recording nothing: the machine's own jitter."""
    late, t_next = [], time.monotonic()
    t_end = t_next + seconds
    while t_next < t_end:
        late.append(time.monotonic() - t_next)
        t_next += 1e-3
        time.sleep(max(0.0, t_next - time.monotonic()))
    return [round(float(np.percentile(np.asarray(late) * 1e3, p)), 3) for p in (50, 99, 100)]


def run(seconds: float, out_dir: Path, workdir: Path, n_frames: int = 15) -> dict:
    """n_frames: distinct synthetic frames per camera, cycled (making them costs ~0.1 s CPU each)."""
    path = workdir / "bench.mcap"
    names = [f"joint{i + 1}" for i in range(N_JOINTS)]
    rec = Recorder(path, joint_names={"leader": names, "follower": names})
    cams = {f"cam{i}": synthetic_frames(n_frames, i) for i in range(4)}
    stop = threading.Event()
    sent_frames = [0]

    def camera(name: str, frames: list[np.ndarray]) -> None:
        period, k, t_next = 1 / 30, 0, time.monotonic()
        while not stop.is_set():
            rec.log_image(name, time.monotonic(), frames[k % len(frames)].copy())  # a new array per grab
            sent_frames[0] += 1
            k += 1
            t_next += period
            time.sleep(max(0.0, t_next - time.monotonic()))

    threads = [threading.Thread(target=camera, args=(n, f), daemon=True) for n, f in cams.items()]
    state = JointState.empty(N_JOINTS)
    state.status[:] = STATUS_ENABLED
    late, log_cost = [], []
    ru0, w0 = resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
    for th in threads:
        th.start()
    period, k, t_next, overruns = 1e-3, 0, time.monotonic(), 0
    t_end = t_next + seconds
    while t_next < t_end:
        now = time.monotonic()
        late.append(now - t_next)
        if now - t_next > period:
            overruns += 1
        phase = k * period
        state.q[:] = np.sin(phase + np.arange(N_JOINTS))
        state.q_dot[:] = np.cos(phase + np.arange(N_JOINTS))
        state.tau_m[:] = 0.3 * state.q
        state.current[:] = 0.1 * state.q
        state.q_cmd[:] = state.q
        state.temperature[:] = 35.0
        c0 = time.perf_counter()
        rec.log_joint_state("leader", now, state)
        rec.log_joint_state("follower", now, state)
        rec.log_external_torque("follower", now, 0.1 * state.q, k % 1000 < 300)
        rec.log_torque_command("leader", now, -0.05 * state.q, 1.0)
        rec.log_loop_timing(now, period, 1e-4, late[-1], overruns)
        log_cost.append(time.perf_counter() - c0)
        k += 1
        t_next += period
        time.sleep(max(0.0, t_next - time.monotonic()))
    stop.set()
    for th in threads:
        th.join()
    c0 = time.monotonic()
    st = rec.close(stall_s=120)
    close_s = time.monotonic() - c0
    ru1, wall = resource.getrusage(resource.RUSAGE_SELF), time.monotonic() - w0
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    late_ms = np.asarray(late) * 1e3
    res = {
        "seconds": seconds, "ticks": k, "frames_sent": sent_frames[0], "frames_written": st.frames_written,
        "dropped_frames": st.dropped_frames, "dropped_samples": st.dropped_samples, "error": st.error,
        "messages_written": st.messages_written, "file_MB": round(path.stat().st_size / 1e6, 1),
        "MB_per_s": round(path.stat().st_size / 1e6 / seconds, 2),
        "cpu_cores_used": round(cpu / wall, 2), "close_s": round(close_s, 2),
        "loop_late_ms_p50_p99_max": [round(float(np.percentile(late_ms, p)), 3) for p in (50, 99, 100)],
        "log_calls_per_tick_us_p50_p99": [round(float(np.percentile(log_cost, p)) * 1e6, 1)
                                          for p in (50, 99)],
        "loop_late_ms_without_recording_p50_p99_max": loop_baseline(min(10.0, seconds)),
        "cpus_on_machine": os.cpu_count(), "load_avg_1min": round(os.getloadavg()[0], 2),
        "switch_interval_s": sys.getswitchinterval(),
    }
    shutil.rmtree(cache_dir(path), ignore_errors=True)
    t0 = time.perf_counter()
    r = Recording(path)  # decode the MCAP and build the cache
    res["read_uncached_s"] = round(time.perf_counter() - t0, 3)
    n_msgs = sum(len(r.topic(t)) for t in r.topics)
    res["read_uncached_msgs_per_s"] = round(n_msgs / res["read_uncached_s"])
    t0 = time.perf_counter()
    r = Recording(path)
    js = [r.topic(f"/{a}/joint_state") for a in ("leader", "follower")]
    dt = time.perf_counter() - t0
    n_js = sum(len(j) for j in js)
    res["read_cached_s"] = round(dt, 4)
    res["read_cached_joint_samples_per_s"] = round(n_js / dt)
    res["from_cache"] = r.from_cache
    out_dir.mkdir(parents=True, exist_ok=True)
    harness.write(out_dir / "recording.json", harness.record("recording", res, simulated=True))
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--out", type=Path, default=harness.OUT, help="folder of recording.json")
    ap.add_argument("--switch-interval", type=float, default=None,
                    help="sys.setswitchinterval [s] for the run (Python default 0.005)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the recording in this folder")
    harness.add_quick(ap, "1 s")
    args = ap.parse_args()
    if args.quick:
        args.seconds = 1.0
    if args.switch_interval:
        sys.setswitchinterval(args.switch_interval)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        res = run(args.seconds, args.out, work, n_frames=3 if args.quick else 15)
    print(json.dumps(res, indent=1))
    ok = res["dropped_frames"] == 0 and res["dropped_samples"] == 0 and not res["error"]
    print("PASS: zero dropped frames and samples" if ok else "FAIL: drops or errors (see above)")
    return 0 if ok or args.quick else 1  # --quick checks the script, not the machine (1 s on a loaded CI)


if __name__ == "__main__":
    sys.exit(main())
