"""A position spring's stiffness on the twin, per joint, stiffness and sign (issue 57 item 4). SIMULATED.

    python -m bench.bench_springs_twin [--data /tmp/factr2_springs] [--out bench/out/springs_twin.json]

sim-piper in lockstep through the Piper driver, its true body differing from the description (the shipped
rig's default), the twin's mechanical effects off (calibration/diagnosis/twin_data.py), one spring
k (q_j - q0) injected through the undeclared-effect hook; train 60 s (seed 0), held out 30 s (seed 100).
Each case is diagnosed twice: with the rigid part held to the description (`--prior-weight 1.0`, the CLI's
default) and nearly free (1e-3, the family bench's). The report's `springs` entry (calibration/diagnosis/
springs.py) gives the stiffness, its refit with the rigid part free and the joint's gravity R^2.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CASES = [(0, -1.5, 0.4), (1, 2.0, 1.0), (1, -1.0, 1.0), (2, -1.0, -1.0), (2, 1.5, -1.0), (3, 0.5, 0.2),
         (4, -0.5, 0.0)]  # (joint, stiffness N*m/rad, rest position rad)


def main() -> int:
    from calibration.diagnosis.report import to_json
    from calibration.diagnosis.twin_data import TwinCase, _spring, diagnose_logs, generate

    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="/tmp/factr2_springs")
    ap.add_argument("--out", default=str(ROOT / "bench/out/springs_twin.json"))
    args = ap.parse_args()
    rows, t0 = [], time.perf_counter()
    for j, k, q0 in CASES:
        case = TwinCase("position_spring", j, _spring(j, k, q0), params={"k": k, "q0": q0})
        tr, he = generate(Path(args.data) / f"spring_j{j}_k{k}", case, 60, 30, reuse=True)
        for pw in (1.0, 1e-3):
            dg = diagnose_logs([tr], [he], prior_weight=pw)
            rep = to_json(dg, {"units": "N*m"})
            first = dg.steps[1].added if len(dg.steps) > 1 else None
            sp = next((s for s in rep.get("springs", []) if s["joint"] == j), None)
            row = {"joint": j, "k_true": k, "q0": q0, "prior_weight": pw,
                   "first": None if first is None else [first["effect"], first["joint"]],
                   "k_found": None if sp is None else sp["stiffness_per_rad"],
                   "k_free_rigid": None if sp is None else sp.get("stiffness_free_rigid_per_rad"),
                   "gravity_r2": None if sp is None else sp["gravity_r2"],
                   "words": None if sp is None else sp["words"]}
            for key in ("k_found", "k_free_rigid"):
                row[key + "_err"] = None if row[key] is None else row[key] / k - 1
            rows.append(row)
            print(json.dumps(row), flush=True)
    out = {"rows": rows, "wall_s": round(time.perf_counter() - t0, 1), "simulated": True}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
