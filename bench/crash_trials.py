"""The app dies (or freezes) beside a twin in a process of its own: what the motors do by themselves
(SIMULATED; docs/faults_crash.md). For bench/faults.py's app_sigkill and app_freeze.

    out = run_crash_trial("teleop", "app_sigkill", "sim-yam", seed=3, folder=Path("/tmp/x"))
    out = run_crash_trial("rollout", "app_freeze", "sim-piper", 4, Path("/tmp/y"), policies=Path("/tmp/p"))

The twin: `python -m hardware.process_twin --hand` (real time; Dynamixel on ptys, CAN on pty links; a
scripted hand on each leader). The app: `factr2 teleop --rig <the twin's app rig>` in real time, recording
(`--record`) for the collect activity, or `factr2 rollout --rig <app rig> --policy RUN` for the rollout
activity (real time, takeover on as on a real rig: the leader follows the follower, the hand may take over):
the real command line, which does not know it talks to a twin. The rollout's policy (crash_policy, trained
once per rig into `policies`) sees the joints and force only (`--obs joints`): the twin in its own process
serves no cameras and no task world, so a policy that looks or observes objects has nothing to run on
here; it has to run, not to succeed. Once
the app has commanded every device for a seeded 1-2 s, the parent sends SIGKILL (or SIGSTOP, then SIGCONT
after the fault's duration) and reads what the twin saw, from the same monotonic clock:
- fallback_ms: from the signal to the moment the last motor was in its fallback (Dynamixel: its Bus Watchdog
  latched -- the emulator's deadline; Damiao: its command timeout's damping; Piper, which has no timeout: the
  last frame from the app, from when it holds that target);
- leader_tau_after_nm: the largest torque any leader servo applied after that moment (must be 0);
- follower_motion_rad: the largest joint excursion of any follower from its pose at the signal, over
  MOTION_WINDOW_S (app_sigkill) or the freeze;
- app_freeze: recovered (the app commanded every device again, its leaders' watchdogs re-armed, it ended by
  Ctrl-C with exit 0 or 130 and no traceback) and the follower's peak speed in the RESUME_WINDOW_S after
  SIGCONT against its peak speed in the same window before the freeze (a jump would be a snap to the leader).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ACTIVE_BEFORE_S = (1.0, 2.0)  # s the app commands every device before the signal (seeded, uniform)
MOTION_WINDOW_S = 1.5  # s after a SIGKILL over which the followers' motion is measured
RESUME_WINDOW_S = 2.0  # s after SIGCONT (and before the freeze) over which the follower's speed is taken
SPEED_DT_S = 0.01  # s: the follower's speed is taken over this interval
AFTER_RESUME_S = 4.0  # s the app runs after SIGCONT before it is stopped with Ctrl-C
START_TIMEOUT_S = 120.0  # s of wall time for the twin to serve and the app to become active
CRASH_RIGS = ("sim-piper", "sim-yam", "sim-bimanual-piper")  # both arm families and the bimanual rig
START_TRIES = 3  # a trial whose app does not start is started again (module doc of run_crash_trial)
POLICY_RECORD_S = 4.0  # s of teleop recorded against a rig's process twin for its rollout policy
POLICY_STEPS = 25  # training steps of that policy (it has to run, not succeed)
MESSAGES_MAX = 20  # the app's hold / coupling lines a trial keeps (the recovery lines are kept past it)


def _wait_for(pred, timeout_s: float, step_s: float = 0.05) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if pred():
            return True
        time.sleep(step_s)
    return False


def _status(folder: Path) -> dict:
    try:
        return json.loads((folder / "status.json").read_text())
    except (OSError, ValueError):
        return {}


def analyse(w: dict, ev: dict, t_sig: float, kind: str, t_cont: float | None = None) -> dict:
    """The trial's measures (module doc) from the twin's samples w (watch.npz) and events ev
    (events.json); t_sig / t_cont: the signals' monotonic times [s]."""
    t = np.asarray(w["t"], float)
    if len(t) < 2 or t[-1] < t_sig:
        return {"error": "the twin recorded nothing after the signal"}
    after = t >= t_sig
    t_end = t_cont if t_cont is not None else np.inf  # a freeze: the fallbacks during it
    per_device: dict[str, float | None] = {}
    deadline: dict[str, float | None] = {}  # the same from the motors' own deadlines (without the twin's lag)
    for name, e in ev["leaders"].items():  # the servos' watchdog deadlines (rig clock = monotonic)
        # when the emulator stopped each servo (its deadline + the twin's wake-up: what the arm felt)
        trips = [(dl, applied) for _, dl, applied in e["watchdog_trips"] if t_sig - 1e-6 <= dl <= t_end]
        armed = len(w["leader_latched"][0]) // max(1, len(ev["leaders"]))  # the joint servos
        full = bool(trips) and len(trips) >= armed
        per_device[name] = (max(a for _, a in trips) - t_sig) * 1e3 if full else None
        deadline[name] = (max(d for d, _ in trips) - t_sig) * 1e3 if full else None
    counts = np.asarray(w["counts"], float)
    n_lead = len(ev["leaders"])
    for k, (name, e) in enumerate(ev["followers"].items()):
        if e["driver"] == "damiao":
            first: dict[int, float] = {}  # each motor's first fallback in the window
            for k_m, x in e["timeouts"]:
                if t_sig - 1e-6 <= x <= t_end:
                    first.setdefault(k_m, x)
            per_device[name] = (max(first.values()) - t_sig) * 1e3 if len(first) == e["motors"] else None
        else:  # no timeout: it holds the last target it got, from the last frame the app sent before t_end
            c = counts[:, n_lead + k]
            changed = np.nonzero((np.diff(c) != 0) & (t[1:] <= t_end))[0]
            last = t[changed[-1] + 1] if len(changed) else t[0]
            per_device[name] = max(0.0, (last - t_sig) * 1e3)
        deadline[name] = per_device[name]
    missing = [n for n, v in per_device.items() if v is None]
    fallback_ms = None if missing else max(per_device.values())
    out = {"fallback_ms": fallback_ms, "fallback_ms_per_device": per_device, "not_fallen_back": missing,
           "fallback_deadline_ms": None if missing else max(deadline.values())}
    tau = np.abs(np.asarray(w["leader_tau"], float))
    end = t_cont if kind == "app_freeze" else np.inf
    if fallback_ms is not None:
        sel = (t > t_sig + fallback_ms * 1e-3 + 1e-9) & (t < end)
        out["leader_tau_after_nm"] = float(tau[sel].max()) if sel.any() else None
    else:
        out["leader_tau_after_nm"] = None
    out["leader_tau_at_signal_nm"] = float(tau[after][0].max()) if after.any() else None
    q = np.asarray(w["follower_q"], float)
    i0 = int(np.argmax(after))
    win = after & (t <= (t_cont if t_cont is not None else t_sig + MOTION_WINDOW_S))
    out["follower_motion_rad"] = float(np.abs(q[win] - q[i0]).max()) if win.any() else None
    if t_cont is not None:
        out["follower_speed_after_resume_rad_s"] = _peak_speed(t, q, t_cont, t_cont + RESUME_WINDOW_S)
        out["follower_speed_before_rad_s"] = _peak_speed(t, q, t_sig - RESUME_WINDOW_S, t_sig)
        tail = (t > t_cont + 0.5) & (t < t_cont + RESUME_WINDOW_S)
        out["traffic_after_resume"] = bool(tail.any() and np.all(counts[tail][-1] > counts[tail][0]))
        lat = np.asarray(w["leader_latched"], bool)
        back = (t > t_cont) & (t < t_cont + RESUME_WINDOW_S)
        out["watchdogs_rearmed"] = bool((~lat[back]).all(axis=1).any()) if back.any() else None
        out["latched_during_freeze"] = bool(lat[(t > t_sig) & (t < t_cont)].all(axis=1).any()) if len(lat) \
            else None
    return out


def _peak_speed(t, q, t0: float, t1: float) -> float | None:
    """Largest joint speed [rad/s] over SPEED_DT_S intervals in [t0, t1]."""
    sel = (t >= t0) & (t <= t1)
    if sel.sum() < 3:
        return None
    ts, qs = t[sel], q[sel]
    k = max(1, int(round(SPEED_DT_S / max(np.median(np.diff(ts)), 1e-4))))
    if len(ts) <= k:
        return None
    v = np.abs(qs[k:] - qs[:-k]) / (ts[k:] - ts[:-k])[:, None]
    return float(v.max())


def trial_messages(log: str) -> list[str]:
    """The app log's hold / coupling / recovery lines: the first MESSAGES_MAX, and every recovery line (a
    re-arm, 'comes back') wherever it is -- on a slow core the start says 20+ holds (stale data, a stalled
    policy) before the freeze, and a plain cut lost the line the trial's checks read."""
    said, kept = ("hold", "coupled", "re-arm", "comes back"), ("re-arm", "comes back")
    lines = [ln for ln in log.splitlines() if any(w in ln for w in said)]
    return [ln for k, ln in enumerate(lines) if k < MESSAGES_MAX or any(w in ln for w in kept)]


def run_crash_trial(activity: str, kind: str, rig: str, seed: int, folder: Path,
                      duration_s: float = 2.0, policies: Path | None = None) -> dict:
    """One trial (module doc); activity "teleop", "collect" (teleop recording) or "rollout" (the policy
    crash_policy trains once per rig into the folder `policies`). A trial whose app did not start (before
    any signal: a connect that timed out on a loaded machine, a refused start) is started again,
    START_TRIES times in all; start_failures says how often and why."""
    if activity not in ("teleop", "collect", "rollout"):
        raise ValueError(f"activity {activity!r}: teleop, collect or rollout")
    if activity == "rollout" and policies is None:
        raise ValueError("the rollout activity needs a folder for its policies")
    policy = crash_policy(rig, policies) if activity == "rollout" else None
    failures = []
    for k in range(START_TRIES):
        out = _trial(activity, kind, rig, seed, folder / f"try{k}", duration_s, policy)
        if out.get("played") or not out.get("error"):
            break
        failures.append(out["error"])
    out["start_failures"] = failures
    return out


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")


def _start_twin(rig: str, seed: int, folder: Path) -> tuple[subprocess.Popen, Path]:
    """The rig's twin in a process of its own, with its scripted hand (module doc): (process, its folder)."""
    twin_dir = folder / "twin"
    twin_dir.mkdir(parents=True, exist_ok=True)
    twin = subprocess.Popen([sys.executable, "-m", "hardware.process_twin", "--rig", rig, "--out",
                             str(twin_dir), "--seed", str(seed), "--hand"], cwd=ROOT, env=_env(),
                            stdout=open(folder / "twin.log", "w"), stderr=subprocess.STDOUT)
    return twin, twin_dir


def _twin_serves(twin: subprocess.Popen, twin_dir: Path) -> bool:
    return _wait_for(lambda: (twin_dir / "endpoints.json").exists() or twin.poll() is not None,
                     START_TIMEOUT_S) and twin.poll() is None


def _stop_twin(twin: subprocess.Popen) -> None:
    """SIGTERM: it writes its record and exits."""
    if twin.poll() is None:
        twin.send_signal(signal.SIGTERM)
    try:
        twin.wait(timeout=60)
    except subprocess.TimeoutExpired:
        twin.kill()
        twin.wait()


def crash_policy(rig: str, folder: Path) -> Path:
    """The rollout activity's policy for a rig, trained once into folder/<rig>/run (reused while its "done"
    marker is there): `factr2 teleop --record --no-cameras` for POLICY_RECORD_S against the rig's process twin
    (the scripted hand moves the leader), then `factr2 train --obs joints` (joints and force only, the tiny
    sizes of tests/rollout_helpers.py) for POLICY_STEPS steps. RuntimeError when a step fails. A recording
    whose app could not connect (a motor of the twin that did not answer in time: the twin's emulators share
    a slow or loaded core with the app) is started again with a fresh twin, START_TRIES times in all, as a
    trial is (run_crash_trial); any other failure is raised at once."""
    from tests.rollout_helpers import TINY

    base = folder / rig
    run = base / "run"
    if (run / "done").exists():
        return run
    base.mkdir(parents=True, exist_ok=True)
    print(f"training the rollout policy of {rig} (once)...", file=sys.stderr, flush=True)
    for k in range(START_TRIES):
        rec = _record_policy_data(rig, base / f"twin{k}", base / "rec")
        if rec.returncode == 0 or not _did_not_connect(rec.stderr) or k == START_TRIES - 1:
            break
        print(f"{rig}: the recording's app did not connect, started again: {rec.stderr.strip()[-200:]}",
              file=sys.stderr, flush=True)
    if rec.returncode != 0:
        raise RuntimeError(f"recording {rig}'s policy data failed: {rec.stderr.strip()[-300:]}")
    sets = [f"{k}={v}" for k, v in TINY.items() if k not in ("backbone", "image_size")]
    cmd = [sys.executable, "-m", "factr2_teleop.cli", "train", str(base / "rec"), "--out", str(run),
           "--obs", "joints", "--policy", "act", "--method", "base", "--steps", str(POLICY_STEPS), "--batch",
           "8", "--include-failed", "--no-progress", "--threads", "1"]
    for s in sets:
        cmd += ["--set", s]
    tr = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=600)
    if tr.returncode != 0:
        raise RuntimeError(f"training {rig}'s policy failed: {(tr.stderr or tr.stdout).strip()[-300:]}")
    (run / "done").write_text("ok")
    return run


def _record_policy_data(rig: str, folder: Path, rec: Path) -> subprocess.CompletedProcess:
    """`factr2 teleop --record rec --no-cameras` for POLICY_RECORD_S against a fresh process twin of the rig
    in folder (a failed try's files removed first)."""
    shutil.rmtree(rec, ignore_errors=True)
    folder.mkdir(parents=True, exist_ok=True)
    twin, twin_dir = _start_twin(rig, 0, folder)
    try:
        if not _twin_serves(twin, twin_dir):
            raise RuntimeError(f"{rig}'s twin did not start: {folder / 'twin.log'}")
        return subprocess.run([sys.executable, "-m", "factr2_teleop.cli", "teleop", "--rig",
                               str(twin_dir / "app_rig.toml"), "--record", str(rec), "--no-cameras",
                               "--seconds", f"{POLICY_RECORD_S:g}"], cwd=ROOT, env=_env(),
                              capture_output=True, text=True, timeout=START_TIMEOUT_S + 60)
    finally:
        _stop_twin(twin)


def _did_not_connect(stderr: str) -> bool:
    """The app ended at connect: a device that did not answer (hardware.errors.DeviceNotFound's texts)."""
    return "does not answer" in stderr or "did not answer" in stderr


def _app_command(activity: str, app_rig: Path, folder: Path, policy: Path | None, seed: int) -> list[str]:
    """The app's command line: ended by the kill, or by Ctrl-C (SIGINT) AFTER_RESUME_S after the freeze."""
    cli = [sys.executable, "-m", "factr2_teleop.cli"]
    if activity == "rollout":  # one operator-marked episode (no key comes: it runs until stopped)
        return cli + ["rollout", "--rig", str(app_rig), "--policy", str(policy), "--episodes", "1",
                      "--max-seconds", "600", "--seed", str(seed)]
    cmd = cli + ["teleop", "--rig", str(app_rig), "--seconds", "600"]
    if activity == "collect":
        cmd += ["--record", str(folder / "rec"), "--no-cameras"]
    return cmd


def _trial(activity: str, kind: str, rig: str, seed: int, folder: Path, duration_s: float,
             policy: Path | None = None) -> dict:
    rng = np.random.default_rng(seed)
    active_for = float(rng.uniform(*ACTIVE_BEFORE_S))
    folder.mkdir(parents=True, exist_ok=True)
    env = _env()
    out: dict = {"rig": rig, "played": False, "error": None, "violations": 0, "safe_ms": None,
                 "stale_ms": None, "recovered": None, "samples_lost": None, "active_before_s": active_for}
    twin, twin_dir = _start_twin(rig, seed, folder)
    app = None
    try:
        if not _twin_serves(twin, twin_dir):
            out["error"] = "the twin did not start"
            return out
        cmd = _app_command(activity, twin_dir / "app_rig.toml", folder, policy, seed)
        app_log = open(folder / "app.log", "w")
        # Ctrl-C must reach it as the operator's would, even when this campaign runs in the background (a
        # shell's background job ignores SIGINT, and Python keeps an ignored SIGINT ignored)
        app = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=app_log, stderr=subprocess.STDOUT,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        def active() -> bool:
            return _status(twin_dir).get("active_s", 0.0) >= active_for or app.poll() is not None

        if not _wait_for(active, START_TIMEOUT_S) or app.poll() is not None:
            tail = (folder / "app.log").read_text(errors="replace").strip().splitlines()[-1:]
            out["error"] = f"the app did not become active (exit {app.poll()}): {' '.join(tail)[:200]}"
            return out
        t_cont = None
        if kind == "app_sigkill":
            t_sig = time.monotonic()
            os.kill(app.pid, signal.SIGKILL)
            time.sleep(MOTION_WINDOW_S + 0.2)
            rc = app.wait(timeout=30)
        else:
            t_sig = time.monotonic()
            os.kill(app.pid, signal.SIGSTOP)
            time.sleep(duration_s)
            t_cont = time.monotonic()
            os.kill(app.pid, signal.SIGCONT)
            time.sleep(AFTER_RESUME_S)
            os.kill(app.pid, signal.SIGINT)  # the operator stops it: Ctrl-C's path
            try:
                rc = app.wait(timeout=60)
            except subprocess.TimeoutExpired:
                app.kill()
                rc = app.wait()
                out["error"] = "the app did not end after the freeze"
        out.update(played=True, exit=rc, t_signal=t_sig, t_cont=t_cont)
    finally:
        if app is not None and app.poll() is None:
            app.kill()
            app.wait()
        _stop_twin(twin)
    log = (folder / "app.log").read_text(errors="replace") if (folder / "app.log").exists() else ""
    out["traceback"] = "Traceback" in log
    out["messages"] = trial_messages(log)
    try:
        w = dict(np.load(twin_dir / "watch.npz"))
        ev = json.loads((twin_dir / "events.json").read_text())
    except (OSError, ValueError) as e:
        out["error"] = out["error"] or f"the twin's record is missing ({e})"
        return out
    m = analyse(w, ev, out["t_signal"], kind, out.get("t_cont"))
    out.update(m)
    out["overruns"] = ev.get("overruns")
    ok_fallback = m.get("fallback_ms") is not None and m.get("leader_tau_after_nm") == 0.0
    if kind == "app_sigkill":
        out["safe_end"] = bool(ok_fallback and out.get("exit") == -9)
    else:
        out["recovered"] = bool(out.get("exit") in (0, 130) and not out["traceback"]
                                and m.get("traffic_after_resume") and m.get("watchdogs_rearmed"))
        out["safe_end"] = bool(ok_fallback and m.get("latched_during_freeze") is not False)
    if activity == "collect":
        out["recording_opens"] = _recording_opens(folder / "rec")
    return out


def _recording_opens(folder: Path) -> bool | None:
    from hardware.recording.reader import open_when_finished

    files = sorted(folder.glob("*.mcap")) if folder.exists() else []
    if not files:
        return None
    try:
        open_when_finished(files[0], 15.0)
        return True
    except Exception:  # noqa: BLE001 -- the outcome to count
        return False
