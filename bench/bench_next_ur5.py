"""NEXT on the real UR5 logs (../shared/data/ur5_kufieta2014, current in A, no arm description): the table of
issue 23 -- NEXT as `factr2 calibrate` trains it by default (`--prior auto` = the data-only grey box here),
plain NEXT (`--prior none`, the paper's), the data-only grey box alone, ridge on hand features, raw current --
on held-out runs the training never saw, plus training times.

    python bench/bench_next_ur5.py [--threads 0] [--max-seconds 60] [--train RUN,...] [--heldout RUN,...]
                                   [--inputs q,qd,dq] [--rate-hz 100] [--hidden 64] [--priors auto,none]
                                   [--gate crossfit|heldout|none] [--validation blocks|runs|auto]

Train: Movement_No1-No6 free-motion runs; held out: Movement_No7_Acc_slow_Verify_Model_short and TEST (other
trajectories). L1 [A] is the mean over joints of the mean |estimate| on the held-out free motion (truth 0).
Writes bench/out/next_ur5.json. The runs with a person pushing the arm have no force sensor (no truth): they
are not scored.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
UR5 = ROOT.parent / "shared" / "data" / "ur5_kufieta2014"
TRAIN_RUNS = ["Movement_No1", "Movement_No2", "Movement_No3_Acc", "Movement_No4_Acc",
              "Movement_No5_Acc_slow_no_disturbance", "Movement_No6_Acc_slow_Verify_Model"]
EVAL_RUNS = ["Movement_No7_Acc_slow_Verify_Model_short", "TEST"]


def run_one(prior: str, train_runs, eval_runs, out: Path, rate_hz: float = 100.0, **cfg_kw) -> dict:
    from calibration.next.train import TrainConfig
    from calibration.report import calibrate_from_logs

    cfg = TrainConfig(device="cpu", prior=prior, **cfg_kw)
    t0 = time.perf_counter()
    rep = calibrate_from_logs([UR5 / f"{r}.npz" for r in train_runs], out,
                              [UR5 / f"{r}.npz" for r in eval_runs], cfg=cfg, rate_hz=rate_hz, plots=False)
    per_file = {f: {m: v["free_l1_mean"] for m, v in ms.items()} for f, ms in rep["files"].items()}
    return {"prior": rep["prior"], "inputs": rep["inputs"], "train_seconds": rep["train_seconds"],
            "seconds_to_within_5pct": rep["train_seconds_to_within_5pct"], "stop": rep["train_stop"],
            "epochs": rep["epochs"], "threads": rep["threads"], "wall_s": time.perf_counter() - t0,
            "free_l1_A": {m: v["free_l1_mean"] for m, v in rep["methods"].items()},
            "free_l1_A_per_joint": {m: v["free_l1"] for m, v in rep["methods"].items()},
            "per_file": per_file, "network_adds": rep["network_adds"],
            "gate": json.loads((out / "next.json").read_text())["model"].get("gate")}


def table(results: dict) -> list[str]:
    """The issue's rows from an `auto` (data-only prior) and a `none` run."""
    auto, plain = results.get("auto"), results.get("none")
    rows = []
    if auto:
        rows += [("NEXT (default: --prior auto = data-only grey box)", auto, "next"),
                 ("data-only grey box alone", auto, "prior"), ("ridge on hand features", auto, "ridge"),
                 ("raw current", auto, "raw")]
    if plain:
        rows.insert(1, ("plain NEXT (--prior none)", plain, "next"))
    files = EVAL_RUNS
    lines = ["| method | held-out L1 [A] | " + " | ".join(files) + " | train s (to 5 %) |",
             "|---|---|" + "---|" * len(files) + "---|"]
    for label, res, m in rows:
        per = " | ".join(f"{res['per_file'].get(f, {}).get(m, float('nan')):.3f}" for f in files)
        tt = (f"{res['train_seconds']:.0f} ({res['seconds_to_within_5pct']:.0f})" if m == "next" else "--")
        lines.append(f"| {label} | {res['free_l1_A'][m]:.3f} | {per} | {tt} |")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--max-seconds", type=float, default=60.0)
    ap.add_argument("--max-epochs", type=int, default=400)
    ap.add_argument("--train", default=",".join(TRAIN_RUNS))
    ap.add_argument("--heldout", default=",".join(EVAL_RUNS))
    ap.add_argument("--inputs", default="q,qd,dq")
    ap.add_argument("--hidden", type=int, default=64)
    ap.add_argument("--history", type=int, default=50)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--priors", default="auto,none")
    ap.add_argument("--gate", default="crossfit", help="TrainConfig.gate: crossfit, heldout, none")
    ap.add_argument("--validation", default="blocks", help="TrainConfig.validation: blocks, runs, auto")
    ap.add_argument("--tag", default="", help="name of this experiment in bench/out/next_ur5.json")
    args = ap.parse_args()
    if not UR5.is_dir():
        print(f"UR5 logs not found at {UR5}: skipped")
        return 0
    out = ROOT / "bench" / "out"
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for prior in args.priors.split(","):
        budget = args.max_seconds if args.max_seconds > 0 else math.inf
        results[prior] = run_one(prior, args.train.split(","), args.heldout.split(","),
                                 out / f"next_ur5_{prior}", threads=args.threads, max_seconds=budget,
                                 max_epochs=args.max_epochs, inputs=args.inputs, hidden=args.hidden,
                                 history=args.history, rate_hz=args.rate_hz, gate=args.gate,
                                 validation=args.validation)
        r = results[prior]
        f = r["free_l1_A"]
        print(f"prior {prior} ({r['prior']}, inputs {r['inputs']}): NEXT {f['next']:.3f} A, prior "
              f"{f['prior'] or float('nan'):.3f}, ridge {f['ridge']:.3f}, raw {f['raw']:.3f}; {r['epochs']} "
              f"epochs, {r['train_seconds']:.0f} s ({r['stop']}), within 5 % after "
              f"{r['seconds_to_within_5pct']:.0f} s, {r['threads']} thread(s); gate {r['gate']}", flush=True)
    print("\n".join(table(results)))
    path = out / "next_ur5.json"
    old = json.loads(path.read_text()) if path.is_file() else {}
    old[args.tag or "default"] = {"args": vars(args), **results}
    path.write_text(json.dumps(old, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
