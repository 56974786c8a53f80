"""The fault campaign on the twin (SIMULATED, lockstep, seeded): per fault kind, N sessions of teleop, each
with one fault at a random time, and what happened (docs/safety.md "Fault campaign").

    python bench/faults.py --seed 0 --per-kind 3 --activities teleop --json /tmp/faults.json
    python bench/faults.py --seed 0 --per-kind 20 --kinds can_busoff,dxl_unplug --json OUT

JSON, per kind: injected, sessions, sessions_safe, safe_ms {p50, p99, max} (start of the fault to the first
follower hold on the wire; over the injections that held), holds, violations (commands outside the limits),
samples_lost (null: these runs do not record yet, see null_why), recoveries (the pair tracked the leader
again after the fault ended), jumps_rejected, errors (sessions that ended in an exception).
Activities: only teleop so far; collect and rollout are #35's next step (a one-line error says so).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from factr2_teleop.demo.fault_run import run_with_faults  # noqa: E402
from hardware.errors import ConfigError  # noqa: E402
from hardware.sim.faults import KINDS, random_schedule  # noqa: E402

ACTIVITIES = ("teleop",)  # collect, rollout: not yet
# camera kinds need sessions that record with cameras (the campaign's sessions do not yet)
CAMPAIGN_KINDS = tuple(k for k in KINDS if not k.startswith("camera_"))
FAULT_WINDOW_S = (0.6, 1.4)  # s of twin time: when a session's fault starts (after the soft start)
TAIL_S = 1.2  # s: the session runs this long after the fault ends (to see the recovery)
SAMPLES_LOST_WHY = "not measured: the campaign's lockstep sessions do not record yet (issue #35, next step)"


def percentiles(ms: list[float]) -> dict:
    """p50 / p99 / max [ms] of the values given; nulls when there are none."""
    if not ms:
        return {"p50": None, "p99": None, "max": None}
    a = np.asarray(ms, dtype=float)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def campaign_kind(kind: str, per_kind: int, seed: int) -> dict:
    """per_kind sessions with one `kind` fault each (seeded times and joints); the kind's JSON row."""
    row = {"injected": 0, "sessions": 0, "sessions_safe": 0, "holds": 0, "violations": 0,
           "samples_lost": None, "recoveries": 0, "jumps_rejected": 0, "errors": 0}
    safe_ms: list[float] = []
    for i in range(per_kind):
        spec = random_schedule(seed * 1000 + i, [kind], 1, *FAULT_WINDOW_S)[0]
        out = run_with_faults([spec], seconds=spec.t_s + spec.duration_s + TAIL_S, seed=seed + i)
        row["sessions"] += 1
        row["injected"] += sum(e["event"] == "start" for e in out.log)
        row["sessions_safe"] += int(out.safe_at_end and out.error is None)
        row["violations"] += out.violations
        row["recoveries"] += int(all(out.recovered))
        row["jumps_rejected"] += out.jumps_rejected
        row["errors"] += int(out.error is not None)
        held = [m for m in out.safe_ms if m is not None]
        row["holds"] += len(held)
        safe_ms += held
    row["safe_ms"] = percentiles(safe_ms)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--per-kind", type=int, default=20, help="sessions (one injection each) per fault kind")
    ap.add_argument("--kinds", default=",".join(CAMPAIGN_KINDS),
                    help="comma-separated fault kinds (default: all but the camera kinds)")
    ap.add_argument("--activities", default="teleop", help="comma-separated; only teleop so far")
    ap.add_argument("--json", required=True, metavar="OUT", help="write the results here")
    args = ap.parse_args(argv)
    try:
        kinds = [k for k in args.kinds.split(",") if k]
        bad = [k for k in kinds if k not in CAMPAIGN_KINDS]
        if bad:
            raise ConfigError(f"fault kind(s) {', '.join(bad)} not in the campaign", where="--kinds",
                              fix=f"use some of {', '.join(CAMPAIGN_KINDS)} (camera kinds: not yet)")
        acts = [a for a in args.activities.split(",") if a]
        later = [a for a in acts if a not in ACTIVITIES]
        if later:
            raise ConfigError(f"activity {', '.join(later)} is not in the campaign yet", where="--activities",
                              fix="use --activities teleop (collect and rollout: issue #35, next step)")
        if args.per_kind < 1:
            raise ConfigError(f"--per-kind {args.per_kind}", where="--per-kind", fix="give 1 or more")
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    result = {"seed": args.seed, "per_kind": args.per_kind, "activities": acts, "simulated": True,
              "null_why": {"samples_lost": SAMPLES_LOST_WHY}, "kinds": {}}
    for kind in kinds:
        row = campaign_kind(kind, args.per_kind, args.seed)
        result["kinds"][kind] = row
        s = row["safe_ms"]
        p99 = "-" if s["p99"] is None else f"{s['p99']:.0f}"
        print(f"{kind:18s} injected {row['injected']:3d}  safe {row['sessions_safe']}/{row['sessions']}  "
              f"holds {row['holds']:3d}  safe_ms p99 {p99:>4s}  violations {row['violations']}  "
              f"recoveries {row['recoveries']}  jumps rejected {row['jumps_rejected']}", flush=True)
    result["wall_s"] = time.perf_counter() - t0
    Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
