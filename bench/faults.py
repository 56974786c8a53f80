"""The fault campaign on the twin (SIMULATED, lockstep, seeded): per activity and fault kind, N trials with
one fault each at a random time, and what happened (docs/faults.md).

    python -m bench.faults --seed 0 --per-kind 3 --json /tmp/faults.json
    python -m bench.faults --seed 0 --per-kind 20 --kinds can_busoff,dxl_unplug --activities teleop,collect \\
        --json OUT

Trials (bench/fault_trials.py): teleop (the demo's operator through a TeleopSession, recorded),
collect (`factr2 collect`'s collect(), one peg-insert episode), rollout (run_rollout of a tiny policy trained
once into OUT.state/). next_killed: teleop only, in real time with NEXT feedback (recovered: feedback back
on). app_sigkill / app_freeze: the app beside a twin in a process of its own (bench/crash_trials.py: teleop
and collect as `factr2 teleop`, recording for collect, rollout as `factr2 rollout` of a policy that sees the
joints and force only, trained once per rig into OUT.state/crash_policies/; over sim-piper, sim-yam and
sim-bimanual-piper in turn;
per kind fallback_ms {p50, p99, max}, leader_tau_after_nm_max, follower_motion_rad, and for the freeze
recovered_after_freeze and jumps). Each other trial is cut TAIL_S after its fault. Resumable: every finished
trial is a line of OUT.trials.jsonl; a run that was killed continues where it stopped (same arguments).
One progress line per trial on stderr.

JSON, per kind (over its activities, and per activity under "activities"): injected (trials whose fault was
played), trials, trials_safe (both arms safe at the end, no error), safe_unobservable (SIGKILL: the twin
dies with the app), safe_ms {p50, p99, max} (fault start -> first follower hold on the wire, over the trials
that held), stale_ms {p50, p99, max} (at that hold, the age of the oldest sample the pair used: from the last
fresh answer, the reaction a partial fault owes), violations (follower commands outside the limits),
samples_lost (follower samples the recording lacks from before the fault, summed; null when nothing recorded),
recoveries (the follower tracked again after the fault ended) of recovery_owed, errors, tracebacks;
cost_s_per_injection per activity (wall).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import harness
from bench.crash_trials import CRASH_RIGS, run_crash_trial
from bench.fault_trials import run_trial
from hardware.errors import ConfigError
from hardware.sim.faults import KINDS, random_schedule

ROOT = Path(__file__).resolve().parents[1]

LEADER_KINDS = ("dxl_unplug", "dxl_overload", "dxl_corrupt", "spike_leader")
# next_killed: the NEXT worker exists only on a real-time clock: its teleop trials run in real time (mode
# next, the demo's NEXT), collect and rollout (lockstep here, NEXT inline) have no worker to kill
NOT_IN_CAMPAIGN = {"next_killed": "collect and rollout: lockstep runs keep NEXT inline (no worker "
                                  "process); teleop plays it in real time"}
# the app killed / frozen beside a twin in a process of its own (bench/crash_trials.py): teleop and
# collect are `factr2 teleop` (recording for collect), rollout is `factr2 rollout`, on the twin's app rig,
# across CRASH_RIGS
CRASH_KINDS = ("app_sigkill", "app_freeze")
ACTIVITY_KINDS = {
    "teleop": tuple(KINDS),
    "collect": tuple(k for k in KINDS if k not in NOT_IN_CAMPAIGN),
    # a rollout's leader is passive (zero torque, not read by the policy): leader faults do not concern it
    "rollout": tuple(k for k in KINDS if k not in NOT_IN_CAMPAIGN and k not in LEADER_KINDS),
}
FAULT_WINDOW_S = (0.6, 1.4)  # s of twin time: when a trial's fault starts (after the soft start)
# a NEXT worker loads for ~2-5 s after the trial starts: its kills span loading and answering
WINDOW_S_BY_KIND = {"next_killed": (0.6, 10.0)}
POLICY_STEPS = 25  # training steps of the rollout trials' tiny policy (it only has to run, not succeed)


def percentiles(ms: list[float]) -> dict:
    """p50 / p99 / max [ms] of the values given; nulls when there are none."""
    if not ms:
        return {"p50": None, "p99": None, "max": None}
    a = np.asarray(ms, dtype=float)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def aggregate(rows: list[dict]) -> dict:
    """One JSON row over trials (run_trial outcomes)."""
    safe_ms = [r["safe_ms"] for r in rows if r.get("safe_ms") is not None]
    stale_ms = [r["stale_ms"] for r in rows if r.get("stale_ms") is not None]
    lost = [r["samples_lost"] for r in rows if r.get("samples_lost") is not None]
    owed = [r for r in rows if r.get("recovered") is not None]
    out = {"injected": sum(bool(r.get("played")) for r in rows), "trials": len(rows),
            "trials_safe": sum(bool(r.get("safe_end")) and not r.get("error") for r in rows),
            "safe_unobservable": sum(r.get("safe_end", False) is None for r in rows),
            "holds": len(safe_ms), "safe_ms": percentiles(safe_ms), "stale_ms": percentiles(stale_ms),
            "violations": sum(int(r.get("violations") or 0) for r in rows),
            "samples_lost": int(sum(lost)) if lost else None,
            "recordings_open": sum(bool(r.get("recording_opens")) for r in rows),
            "recoveries": sum(bool(r["recovered"]) for r in owed), "recovery_owed": len(owed),
            "errors": sum(bool(r.get("error")) for r in rows),
            "tracebacks": sum(bool(r.get("traceback")) for r in rows)}
    if any("fallback_ms" in r for r in rows):
        out.update(crash_aggregate(rows))
    return out


def crash_aggregate(rows: list[dict]) -> dict:
    """The crash kinds' measures (bench/crash_trials.py) over trials."""
    from factr2_teleop.teleop.soft_start import SoftStartConfig

    def vals(key):
        return [r[key] for r in rows if r.get(key) is not None]

    tau = vals("leader_tau_after_nm")
    out = {"fallback_ms": percentiles(vals("fallback_ms")),
           "fallback_deadline_ms": percentiles(vals("fallback_deadline_ms")),
           "twin_overruns": int(sum(r.get("overruns") or 0 for r in rows)),
           "fallback_missing": sum(r.get("fallback_ms") is None for r in rows),
           "leader_tau_after_nm_max": max(tau) if tau else None,
           "leader_tau_at_signal_nm": percentiles(vals("leader_tau_at_signal_nm")),
           "follower_motion_rad": percentiles(vals("follower_motion_rad")),
           "rigs": sorted({r.get("rig") for r in rows if r.get("rig")})}
    per_dev: dict[str, list] = {}
    for r in rows:
        for dev, ms in (r.get("fallback_ms_per_device") or {}).items():
            if ms is not None:
                per_dev.setdefault(f"{r.get('rig')}:{dev}", []).append(ms)
    out["fallback_ms_per_device"] = {k: percentiles(v) for k, v in sorted(per_dev.items())}
    if any(r.get("t_cont") for r in rows):
        limit = float(np.max(SoftStartConfig().rate_limit_rad_s))
        sp = vals("follower_speed_after_resume_rad_s")
        out.update({"follower_speed_after_resume_rad_s": percentiles(sp),
                    "follower_speed_before_rad_s": percentiles(vals("follower_speed_before_rad_s")),
                    "jump_limit_rad_s": limit, "jumps": sum(v > limit for v in sp),
                    "recovered_after_freeze": sum(bool(r.get("recovered")) for r in rows)})
    return out


def _policy(state: Path) -> Path:
    """The rollout trials' tiny policy, trained once (a held-still peg-insert recording, 25 steps)."""
    run = state / "policy" / "run"
    if not (run / "done").exists():
        from tests.rollout_helpers import record_task_session, train_tiny

        (state / "policy").mkdir(parents=True, exist_ok=True)
        print("training the rollout trials' tiny policy (once)...", file=sys.stderr, flush=True)
        train_tiny(record_task_session(state / "policy"), run, policy="act", steps=POLICY_STEPS)
        (run / "done").write_text("ok")
    return run


def _plan(args) -> list[tuple[str, str, int]]:
    kinds = [k for k in args.kinds.split(",") if k] if args.kinds else None
    acts = [a for a in args.activities.split(",") if a]
    bad = [a for a in acts if a not in ACTIVITY_KINDS]
    if bad:
        raise ConfigError(f"unknown activity {', '.join(bad)}", where="--activities",
                          fix=f"use some of {', '.join(ACTIVITY_KINDS)}")
    if kinds:
        bad = [k for k in kinds if k not in KINDS]
        if bad:
            raise ConfigError(f"unknown fault kind {', '.join(bad)}", where="--kinds", fix=f"use some of "
                              f"{', '.join(KINDS)}")
    if args.per_kind < 1:
        raise ConfigError(f"--per-kind {args.per_kind}", where="--per-kind", fix="give 1 or more")
    return [(a, k, i) for k in (kinds or KINDS) for a in acts if k in ACTIVITY_KINDS[a]
            for i in range(args.per_kind)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--per-kind", type=int, default=20, help="trials (one injection each) per kind and "
                    "activity")
    ap.add_argument("--kinds", default="", help="comma-separated fault kinds (default: all)")
    ap.add_argument("--activities", default="teleop,collect,rollout", help="comma-separated")
    ap.add_argument("--json", required=True, metavar="OUT",
                    help="write the results here (a bench/harness.py record named after OUT)")
    harness.add_quick(ap, "one spike_leader trial in teleop")
    args = ap.parse_args(argv)
    if args.quick:
        args.per_kind, args.kinds, args.activities = 1, "spike_leader", "teleop"
    try:
        plan = _plan(args)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    out = Path(args.json)
    journal = out.with_name(out.name + ".trials.jsonl")
    state = out.with_name(out.name + ".state")
    done = {}
    if journal.exists():  # resume: what a killed run finished
        for line in journal.read_text().splitlines():
            try:
                r = json.loads(line)
            except ValueError:
                continue  # a line cut by the kill
            if r.get("seed") == args.seed:
                done[(r["activity"], r["kind"], r["i"])] = r
    todo = [p for p in plan if p not in done]
    print(f"{len(plan)} trials, {len(plan) - len(todo)} done before, {len(todo)} to run", file=sys.stderr)
    policy = _policy(state) if any(a == "rollout" and k not in CRASH_KINDS for a, k, _ in todo) else None
    t0 = time.perf_counter()
    with journal.open("a") as jf, tempfile.TemporaryDirectory(prefix="factr2-faults-") as tmp:
        for n, (act, kind, i) in enumerate(todo, 1):
            if kind in CRASH_KINDS:
                rig = CRASH_RIGS[i % len(CRASH_RIGS)]
                text = f"{kind}@active+1..2s" + (f":{KINDS[kind][1]:g}" if KINDS[kind][1] else "") + f" {rig}"
                t_s = time.perf_counter()
                r = run_crash_trial(act, kind, rig, args.seed * 1000 + i, Path(tmp) / f"{act}-{kind}-{i}",
                                    KINDS[kind][1], policies=state / "crash_policies")
                r["wall_s"] = time.perf_counter() - t_s
            else:
                lo, hi = WINDOW_S_BY_KIND.get(kind, FAULT_WINDOW_S)
                spec = random_schedule(args.seed * 1000 + i, [kind], 1, lo, hi + KINDS[kind][1], gap_s=0.0)[0]
                r = run_trial(act, spec, args.seed + i, Path(tmp) / f"{act}-{kind}-{i}", policy)
                text = spec.text()
            r = {k: v for k, v in r.items() if k not in ("log", "messages")}
            r.update(activity=act, kind=kind, i=i, seed=args.seed, spec=text)
            jf.write(json.dumps(r, default=str) + "\n")
            jf.flush()
            done[(act, kind, i)] = r
            el = time.perf_counter() - t0
            safe = {True: "safe", False: "NOT SAFE", None: "safe n/a"}[r.get("safe_end")]
            ms = "-" if r.get("safe_ms") is None else f"{r['safe_ms']:.0f} ms"
            if r.get("fallback_ms") is not None:
                moved = r.get("follower_motion_rad") or 0.0
                ms = f"{ms}, motors' fallback {r['fallback_ms']:.0f} ms, leader torque after " \
                     f"{r.get('leader_tau_after_nm')}, follower moved {moved:.3f} rad"
            print(f"[{n}/{len(todo)}] {act} {text}: {safe}, hold {ms}, lost {r.get('samples_lost')}, "
                  f"recovered {r.get('recovered')}{', ERROR ' + str(r['error']) if r.get('error') else ''} "
                  f"({r['wall_s']:.1f} s; ETA {el / n * (len(todo) - n):.0f} s)", file=sys.stderr, flush=True)
    rows = [done[p] for p in plan]
    acts = sorted({a for a, _, _ in plan})
    result = {"seed": args.seed, "per_kind": args.per_kind, "activities": acts, "simulated": True,
              "not_in_campaign": dict(NOT_IN_CAMPAIGN), "kinds": {},
              "cost_s_per_injection": {a: float(np.mean([r["wall_s"] for r in rows if r["activity"] == a]))
                                       for a in acts},
              "wall_s_this_run": time.perf_counter() - t0}
    for kind in dict.fromkeys(k for _, k, _ in plan):
        mine = [r for r in rows if r["kind"] == kind]
        row = aggregate(mine)
        row["activities"] = {a: aggregate([r for r in mine if r["activity"] == a])
                             for a in acts if any(r["activity"] == a for r in mine)}
        result["kinds"][kind] = row
    harness.write(out, harness.record(out.stem, result, simulated=True))
    for kind, row in result["kinds"].items():
        s = row["safe_ms"]
        p99 = "-" if s["p99"] is None else f"{s['p99']:.0f}"
        print(f"{kind:18s} injected {row['injected']:3d}  safe {row['trials_safe']}/{row['trials']}  "
              f"safe_ms p99 {p99:>4s}  violations {row['violations']}  lost {row['samples_lost']}  "
              f"recoveries {row['recoveries']}/{row['recovery_owed']}  errors {row['errors']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
