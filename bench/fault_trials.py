"""One fault-campaign trial per activity (SIMULATED, lockstep, seeded), for bench/faults.py: a short
run of teleop, collect or rollout on the sim-piper twin with one fault, measured the same way.

    out = run_trial("collect", parse_fault("can_busoff@1.0:0.3"), seed=3, folder=Path("/tmp/x"))
    out = {"played", "safe_end", "safe_ms", "violations", "samples_lost", "recovered", "error", ...}

teleop: the demo task's operator drives the leader through TeleopSession (factr2_teleop/demo/fault_run.py),
recorded. collect: `factr2 collect`'s collect() on peg-insert (feedback dob), one episode cut TAIL_S after the
fault. rollout: run_rollout with a tiny policy trained once (tests/rollout_helpers.py), recorded. The signal
kinds kill the process: they run in a child (`python -m bench.fault_trials --child ...`) and the parent
checks its exit and its recording.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

TAIL_S = 1.2  # s of twin time a trial runs after its fault ends (to see the recovery)
NEXT_TAIL_S = 10.0  # s (real time) after a NEXT worker's kill: a new worker starts, loads torch, warms up
SIGNAL_KINDS = ("app_sigterm", "app_sigkill")
COLLECT_TASK = "peg-insert"
WRITER_FINISH_S = 15.0  # s: a killed app's writer process finishes the file within this (wall)
SMALL_FS_MIB = 16  # MiB: the tmpfs a disk_full trial records on (frames of a camera trial fit before)


class Wire:
    """Command observer at the wire: (t_sent, hold) of every follower command, the leader's last torque."""

    def __init__(self, limits):
        self.lo, self.hi = np.asarray(limits.q_min) - 1e-9, np.asarray(limits.q_max) + 1e-9
        self.t, self.hold, self.violations, self.leader_tau = [], [], 0, None

    def __call__(self, t_issued, t_sent, safe) -> None:
        q = np.asarray(safe.q, dtype=float)
        self.t.append(float(t_sent))
        self.hold.append(bool(safe.hold))
        self.violations += int(not ((q >= self.lo) & (q <= self.hi)).all())

    def leader(self, t_issued, t_sent, safe) -> None:
        self.leader_tau = np.asarray(safe.tau, dtype=float)


class Watch:
    """What a trial's campaign measure needs: the wire of its first pair, the ticks it recorded."""

    def __init__(self, ts, rig_session):
        from factr2_teleop.demo.fault_run import fresh_times

        self._fresh_times = fresh_times  # per tick: looked up once here, not imported in every tick
        self.ts, self.s = ts, rig_session
        pair = ts.pairs[0]
        self.wire = Wire(pair.follower.safety.limits)
        pair.follower.add_command_observer(self.wire)
        pair.leader.add_command_observer(self.wire.leader)
        self.t_ticks: list[float] = []
        self.t_all: list[float] = []  # every tick of the pair [s], and the sample times it used
        self.t_samples: list[tuple[float, float]] = []
        self.rec_path = None
        first = pair.cfg.name
        ts.hooks.append(lambda r: self._tick(r) if r.pair == first else None)

    def _tick(self, r) -> None:
        self.t_all.append(r.t)
        prev = self.t_samples[-1] if self.t_samples else None
        self.t_samples.append(self._fresh_times(prev, r.follower, r.leader))
        rec = self.ts.recording
        if rec is not None and rec.recording:
            self.rec_path = rec.path
            self.t_ticks.append(r.t)

    def outcome(self, status_error=None, error=None) -> dict:
        from factr2_teleop.demo.fault_run import REACT_WINDOW_S, check_recording, data_age_ms

        twin = self.s.twin
        log = list(twin.faults.log) if twin.faults is not None else []
        off = twin.rig_time() - twin.t
        t, hold = np.asarray(self.wire.t), np.asarray(self.wire.hold, bool)
        starts = [e for e in log if e["event"] == "start"]
        ends = [e for e in log if e["event"] == "end"]
        out = {"played": bool(starts) and all(e.get("played", True) for e in starts), "error": error,
               "violations": self.wire.violations, "log": log,
               "messages": list(self.ts.loop.snapshot().messages)}
        tau = self.wire.leader_tau
        out["safe_end"] = bool(len(hold) and hold[-1] and (tau is None or np.all(tau == 0.0)))
        out["safe_ms"], out["stale_ms"], out["recovered"] = None, None, None
        if starts:
            t0 = starts[0]["t_s"] + off
            t1 = (ends[0]["t_s"] if ends else starts[0]["t_s"]) + off
            after = t[hold & (t >= t0) & (t <= t1 + REACT_WINDOW_S)]
            out["safe_ms"] = float((after[0] - t0) * 1e3) if len(after) else None
            out["stale_ms"] = data_age_ms(float(after[0]) if len(after) else None, self.t_all, self.t_samples)
            out["recovered"] = bool(np.any(~hold[:-1] & (t[:-1] > t1 + REACT_WINDOW_S)))  # last: the stop
        out["samples_lost"], out["recording_opens"], out["recording_error"] = None, None, status_error
        if self.rec_path is not None:
            t_fault = (starts[0]["t_s"] + off) if starts else np.inf
            rc = check_recording(self.rec_path, self.t_ticks, t_fault, status_error)
            out["samples_lost"], out["recording_opens"] = rc.lost_before_fault, rc.opens
            out["ticks_before_fault"] = rc.ticks_before_fault
        return out


def _teleop(spec, seed: int, folder: Path) -> dict:
    from factr2_teleop.demo.fault_run import run_with_faults

    if spec.kind == "next_killed":  # NEXT is a process of its own only on a real-time clock
        out = run_with_faults([spec], seconds=spec.t_s + NEXT_TAIL_S, seed=seed, record_dir=folder,
                              mode="next", clock="realtime")
        said = [m[2] for m in out.messages]
        back = any("feedback back on" in m for m in said)
        res = _teleop_outcome(out, recovered=back)
        res["worker_restarted"] = any("restarting it" in m for m in said)
        res["killed_while_loading"] = any("ended while loading" in m for m in said)
        return res
    out = run_with_faults([spec], seconds=spec.t_s + spec.duration_s + TAIL_S, seed=seed, record_dir=folder,
                          cameras=spec.kind.startswith("camera_"))
    return _teleop_outcome(out)


def _teleop_outcome(out, recovered=None) -> dict:
    """A teleop run_with_faults outcome as a campaign row; recovered: the kind's own test of it (else the
    loop's re-coupling after each fault that ended)."""
    rc = out.recording
    ends = [e for e in out.log if e["event"] == "end"]
    starts = [e for e in out.log if e["event"] == "start"]
    return {"played": bool(starts) and all(e.get("played", True) for e in starts), "error": out.error,
            "violations": out.violations, "safe_end": out.safe_at_end,
            "safe_ms": out.safe_ms[0] if out.safe_ms else None,
            "stale_ms": out.stale_ms[0] if out.stale_ms else None,
            "recovered": recovered if recovered is not None else (all(out.recovered) if ends else None),
            "samples_lost": rc.lost_before_fault,
            "recording_opens": rc.opens, "recording_error": rc.error,
            "ticks_before_fault": rc.ticks_before_fault, "log": out.log, "messages": out.messages}


def _collect(spec, seed: int, folder: Path) -> dict:
    from factr2_teleop.tasks.run import CollectConfig, collect

    box = {}

    def on_session(ts, s):
        box["w"] = w = Watch(ts, s)
        t_stop = spec.t_s + spec.duration_s + TAIL_S + (s.twin.rig_time() - s.twin.t)
        ts.hooks.append(lambda r: ts.loop.stop() if r.t >= t_stop else None)
        return w

    err = None
    try:
        res = collect(CollectConfig(task=COLLECT_TASK, episodes=1, out=str(folder), seed=seed, mode="dob",
                                    cameras=spec.kind.startswith("camera_"), faults=[spec],
                                    on_session=on_session), progress=False)
        rec_err = res.get("recording_error")
    except Exception as e:  # noqa: BLE001 -- the outcome to count
        err, rec_err = f"{type(e).__name__}: {e}", None
    if "w" not in box:
        return {"played": False, "error": err}
    return box["w"].outcome(rec_err, err)


def _rollout(spec, seed: int, folder: Path, policy: Path) -> dict:
    from factr2_teleop.session.rollout import RolloutHooks, RolloutOptions, run_rollout

    box, err = {}, None

    def on_start(ts, target, eps):
        box["w"] = Watch(ts, ts.session)

    try:
        run_rollout(RolloutOptions(rig="sim-piper", policy=policy, task=COLLECT_TASK, episodes=1,
                                   seed=1000 + seed, record=folder, progress=False,
                                   max_seconds=spec.t_s + spec.duration_s + TAIL_S, faults=[spec]),
                    RolloutHooks(on_start=on_start))
    except Exception as e:  # noqa: BLE001 -- the outcome to count
        err = f"{type(e).__name__}: {e}"
    if "w" not in box:
        return {"played": False, "error": err}
    w = box["w"]
    said = [m[2] for m in w.ts.loop.snapshot().messages if m[1] == "recording"]
    return w.outcome(said[0] if said else None, err)


def run_in_process(activity: str, spec, seed: int, folder: Path, policy: Path | None) -> dict:
    if activity == "teleop":
        return _teleop(spec, seed, folder)
    if activity == "collect":
        return _collect(spec, seed, folder)
    return _rollout(spec, seed, folder, policy)


def run_trial(activity: str, spec, seed: int, folder: Path, policy: Path | None = None) -> dict:
    """One trial; a signal kind runs in a child process (it ends the process that plays it)."""
    folder.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    mounted = spec.kind == "disk_full" and _mount_small_fs(folder)  # else: not played (said in its log)
    try:
        out = _signal_trial(activity, spec, seed, folder, policy) if spec.kind in SIGNAL_KINDS else \
            run_in_process(activity, spec, seed, folder, policy)
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(folder)], check=False)
    out["wall_s"] = time.perf_counter() - t0
    return out


def _mount_small_fs(folder: Path) -> bool:
    """A SMALL_FS_MIB tmpfs at folder for disk_full to fill (root with CAP_SYS_ADMIN); False if not."""
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={SMALL_FS_MIB}m", "tmpfs", str(folder)],
                       capture_output=True)
    return r.returncode == 0


def _signal_trial(activity, spec, seed, folder, policy) -> dict:
    """The child runs the trial and is signalled at spec.t_s (twin time): exit 143 after a safe stop
    (SIGTERM) or killed (-9). Samples lost: the recorded follower samples against a full grid from the first
    one to the signal."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    r = subprocess.run([sys.executable, __file__, "--child", activity, spec.text(), str(seed), str(folder),
                        str(policy or "")], capture_output=True, text=True, env=env, timeout=600)
    out = {"played": True, "error": None if r.returncode in (143, -9) else f"exit {r.returncode}",
           "violations": 0, "safe_ms": None, "stale_ms": None, "recovered": None, "exit": r.returncode,
           "traceback": "Traceback" in r.stderr,
           # SIGTERM: Ctrl-C's path made the arms safe (said); SIGKILL: the twin died with the app, the
           # arms' own command timeouts are not observable here
           "safe_end": ("stopped safely" in r.stderr) if spec.kind == "app_sigterm" else None}
    from hardware.recording.reader import open_when_finished

    files = sorted(folder.glob("*.mcap"))
    out["recording_opens"], out["samples_lost"] = False, None
    if files:
        try:
            rec = open_when_finished(files[0], WRITER_FINISH_S)
            t = rec.topic("/follower/joint_state").t
            out["recording_opens"], out["recording_truncated"] = True, rec.truncated
            if len(t) > 2:
                dt = float(np.median(np.diff(t)))
                # the ticks strictly before the signal (the tick it lands in is cut short by it)
                expect = int(np.ceil((min(spec.t_s, t[-1] + dt) - t[0]) / dt - 1e-6))
                out["samples_lost"] = max(0, expect - int(np.sum(t < spec.t_s - 1e-9)))
        except Exception as e:  # noqa: BLE001
            out["error"] = f"recording does not open: {e}"
    return out


def _child(argv: list[str]) -> int:
    import signal

    from factr2_teleop.cli import Terminated, _on_sigterm  # the app's SIGTERM path
    from hardware.sim.faults import parse_fault

    activity, text, seed, folder, policy = argv
    spec = parse_fault(text)
    signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        run_in_process(activity, spec, int(seed), Path(folder), Path(policy) if policy else None)
    except Terminated:
        pass
    if spec.kind == "app_sigterm":  # (a rollout ends its episode itself on the interrupt and returns)
        print("terminated (SIGTERM): stopped safely", file=sys.stderr)
        return 143
    return 0


if __name__ == "__main__" and sys.argv[1:2] == ["--child"]:
    sys.exit(_child(sys.argv[2:]))
