"""What limits NEXT on the real UR5 logs (issue 23 item 4): one experiment per factor, chosen by
cross-validation on the TRAINING runs only, then scored once on the held-out runs.

Every variant of calibration.next.train.TrainConfig below is trained (`--prior auto` = the data-only grey box,
as `factr2 calibrate` does for an arm it has no description of) on
  - each leave-one-run-out fold of the six training runs (train on five, score the sixth): the selection
    signal, never the held-out runs;
  - all six training runs, scored on the held-out runs (Movement_No7_Acc_slow_Verify_Model_short, TEST): the
    report.
Ensembles average the external-current estimates of the `default` variant's seeds (same data, seeds
0..S-1). Scores are L1 [A], mean over joints of mean |estimate| on free motion (truth 0); ridge on hand
features and the grey box alone are reported per fold as references.

    python bench/next_ur5_experiments.py --out DIR [--workers N] [--variants a,b] [--data PATH]

Each run uses one thread; `--workers` runs (default: every core) in parallel. Writes DIR/experiments.json and
prints a table. The budget is the product's (60 s per training) unless a variant says otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import types
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from bench.bench_next_ur5 import EVAL_RUNS, TRAIN_RUNS, UR5

ROOT = Path(__file__).resolve().parents[1]

SEEDS = 3  # seeds of the SEEDED variants (seed spread and the ensemble)
# name (its --variants key: the part before the first space) -> TrainConfig fields
VARIANTS: dict[str, dict] = {
    "default": {},  # since issue 23 item 4: the cross-fitted per-joint gate (calibration.next.gate)
    "blocks (before: block validation, no gate)": {"gate": "none"},
    "runs-gate (whole-run validation, gate fitted on that run)": {"validation": "runs", "gate": "heldout"},
    "runs-nogate (whole-run validation, no gate)": {"validation": "runs", "gate": "none"},
    "long (150 s budget, 20 epochs)": {"max_seconds": 150.0, "max_epochs": 20},
    "short (3 epochs)": {"max_epochs": 3, "warmup": 3},
    "q-qd-inputs (no q_cmd - q)": {"inputs": "q,qd"},
    "history 25": {"history": 25},
    "hidden 128": {"hidden": 128},
    "robust normaliser": {"normalize": "robust"},
    "input noise 0.1 (augmentation)": {"input_noise": 0.1},
    "weight decay 1e-2": {"weight_decay": 1e-2},
    "plain (--prior none)": {"prior": "none"},
}
SEEDED = ("default", "blocks", "runs-gate", "runs-nogate")  # keys of the variants trained with SEEDS seeds


def _pin_stub() -> None:
    """The UR5 path needs no rigid-body model (no arm description): where pinocchio is not installed (a
    bare experiment machine) a placeholder module lets the imports through; any use of it fails loudly."""
    try:
        import pinocchio  # noqa: F401
    except ImportError:
        mod = types.ModuleType("pinocchio")

        def _missing(name):
            raise AttributeError(f"pinocchio is not installed here (pinocchio.{name} was asked for)")

        mod.__getattr__ = _missing
        sys.modules["pinocchio"] = mod


def run_one(job: dict) -> dict:
    """One training + evaluation (a worker process, one thread)."""
    _pin_stub()
    import torch

    torch.set_num_threads(1)
    from calibration.next.train import TrainConfig
    from calibration.report import calibrate_from_logs

    data = Path(job["data"])
    kw = {"max_seconds": 60.0, **job["kw"]}
    cfg = TrainConfig(**{"device": "cpu", "prior": "auto", "threads": 1, "seed": job["seed"], **kw})
    t = time.perf_counter()
    rep = calibrate_from_logs([data / f"{r}.npz" for r in job["train"]], job["out"],
                              [data / f"{r}.npz" for r in job["eval"]], cfg=cfg, plots=False)
    model = json.loads((Path(job["out"]) / "next.json").read_text())["model"]
    return {**{k: job[k] for k in ("variant", "fold", "seed", "out")}, "wall_s": time.perf_counter() - t,
            "gate": model.get("gate"),
            "train_seconds": rep["train_seconds"], "epochs": rep["epochs"], "stop": rep["train_stop"],
            "l1": {m: v["free_l1_mean"] for m, v in rep["methods"].items()},
            "per_file": {f: {m: v["free_l1_mean"] for m, v in ms.items()} for f, ms in rep["files"].items()}}


def ensemble_l1(outs: list[str], files: list[str]) -> float:
    """L1 [A] of the mean of several runs' NEXT estimates (same evaluation files, same samples)."""
    errs = []
    for f in files:
        est = np.mean([np.load(Path(o) / "estimates" / f"{f}.npz")["tau_ext_next"] for o in outs], axis=0)
        errs.append(np.abs(est[np.all(np.isfinite(est), axis=1)]))  # as report.score: finite rows only
    return float(np.concatenate(errs).mean(0).mean())


def jobs_for(variants: list[str], data: Path, out: Path, n_folds: int = len(TRAIN_RUNS)) -> list[dict]:
    folds = [("heldout", TRAIN_RUNS, EVAL_RUNS)] + [(r, [x for x in TRAIN_RUNS if x != r], [r])
                                                   for r in TRAIN_RUNS]
    jobs = []
    for v in variants:
        for seed in range(SEEDS if v.split(" ")[0] in SEEDED else 1):
            for fold, train, ev in folds[:n_folds + 1]:
                name = f"v{list(VARIANTS).index(v)}_s{seed}_{fold}"
                jobs.append({"variant": v, "fold": fold, "seed": seed, "train": train, "eval": ev,
                             "kw": VARIANTS[v], "data": str(data), "out": str(out / name)})
    return jobs


def _cv_mean(cv: list[dict], m: str) -> float:
    vals = [r["l1"][m] for r in cv]
    return float(np.mean(vals)) if cv and None not in vals else float("nan")  # None: no prior (plain)


def _held(held: dict | None, m: str) -> float:
    return held["l1"][m] if held and held["l1"][m] is not None else float("nan")


def summarise(results: list[dict]) -> dict:
    out = {}
    for v in dict.fromkeys(r["variant"] for r in results):
        rs = [r for r in results if r["variant"] == v and r["seed"] == 0]
        cv = [r for r in rs if r["fold"] != "heldout"]
        held = next((r for r in rs if r["fold"] == "heldout"), None)
        row = {"cv_next": _cv_mean(cv, "next"), "cv_prior": _cv_mean(cv, "prior"),
               "cv_ridge": _cv_mean(cv, "ridge"), "heldout_next": _held(held, "next"),
               "heldout_prior": _held(held, "prior"), "heldout_ridge": _held(held, "ridge"),
               "heldout_per_file": held["per_file"] if held else None,
               "train_seconds": float(np.mean([r["train_seconds"] for r in rs])),
               "epochs": float(np.mean([r["epochs"] for r in rs]))}
        seeds = [r for r in results if r["variant"] == v and r["fold"] == "heldout"]
        if len(seeds) > 1:
            row["heldout_next_seeds"] = [r["l1"]["next"] for r in seeds]
            row["cv_next_seeds"] = [_cv_mean([r for r in results if r["variant"] == v and r["seed"] == s
                                              and r["fold"] != "heldout"], "next")
                                    for s in sorted({r["seed"] for r in seeds})]
            row["heldout_gate_seeds"] = [r["gate"] for r in seeds]
            row["heldout_ensemble"] = ensemble_l1([r["out"] for r in seeds], EVAL_RUNS)
            cv_ens = []
            for fold in TRAIN_RUNS:
                fs = [r for r in results if r["variant"] == v and r["fold"] == fold]
                if len(fs) > 1:
                    cv_ens.append(ensemble_l1([r["out"] for r in fs], [fold]))
            row["cv_ensemble"] = float(np.mean(cv_ens)) if cv_ens else None
        out[v] = row
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--data", default=str(UR5))
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--variants", default=",".join(v.split(" ")[0] for v in VARIANTS))
    ap.add_argument("--folds", type=int, default=len(TRAIN_RUNS), help="CV folds used (smoke: 1)")
    ap.add_argument("--max-seconds", type=float, default=None, help="override every budget (smoke runs)")
    args = ap.parse_args()
    data, out = Path(args.data), Path(args.out)
    if not (data / "TEST.npz").is_file():
        print(f"UR5 logs not found at {data}: skipped")
        return 0
    out.mkdir(parents=True, exist_ok=True)
    want = args.variants.split(",")
    variants = [v for v in VARIANTS if v.split(" ")[0] in want]
    jobs = jobs_for(variants, data, out, args.folds)
    if args.max_seconds is not None:
        for j in jobs:
            j["kw"] = {**j["kw"], "max_seconds": args.max_seconds}
    # the long runs first: the pool then ends together
    jobs.sort(key=lambda j: -j["kw"].get("max_seconds", 60.0))
    print(f"{len(jobs)} runs on {args.workers} workers", flush=True)
    t0, results = time.perf_counter(), []
    import multiprocessing as mp

    with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn")) as ex:
        futs = [ex.submit(run_one, j) for j in jobs]
        for f in as_completed(futs):
            r = f.result()
            results.append(r)
            l1 = {m: float("nan") if v is None else v for m, v in r["l1"].items()}  # no prior: nan
            print(f"  {time.perf_counter() - t0:5.0f} s  {r['variant']} seed {r['seed']} {r['fold']}: "
                  f"next {l1['next']:.3f} prior {l1['prior']:.3f} ridge {l1['ridge']:.3f} "
                  f"({r['epochs']} epochs, {r['train_seconds']:.0f} s)", flush=True)
    summary = summarise(results)
    (out / "experiments.json").write_text(json.dumps({"runs": results, "summary": summary,
                                                      "wall_s": time.perf_counter() - t0,
                                                      "cpus": os.cpu_count()}, indent=1))
    print("| variant | CV NEXT | CV grey box | CV ridge | held-out NEXT | grey box | ridge | train s |")
    print("|---|---|---|---|---|---|---|---|")
    for v, r in summary.items():
        print(f"| {v} | {r['cv_next']:.3f} | {r['cv_prior']:.3f} | {r['cv_ridge']:.3f} | "
              f"{r['heldout_next']:.3f} | {r['heldout_prior']:.3f} | {r['heldout_ridge']:.3f} | "
              f"{r['train_seconds']:.0f} |")
        if "heldout_ensemble" in r:
            seeds = ", ".join(f"{x:.3f}" for x in r["heldout_next_seeds"])
            cv_seeds = ", ".join(f"{x:.3f}" for x in r["cv_next_seeds"])
            print(f"| {v}: seeds | {cv_seeds} | | | {seeds} | | | |")
            print(f"| {v}: ensemble of {len(r['heldout_next_seeds'])} seeds | {r['cv_ensemble']:.3f} | | | "
                  f"{r['heldout_ensemble']:.3f} | | | |")
            for g in r["heldout_gate_seeds"]:
                if g is not None:
                    print(f"|   gate (all six runs) | {' '.join(f'{x:.2f}' for x in g)} | | | | | | |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
