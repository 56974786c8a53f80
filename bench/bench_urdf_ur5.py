"""NEXT on the real UR5 logs with the URDF-identified prior (issue 34 item 4): hardware/arms/ur5.urdf imported
(`factr2 arm import`), the identified prior with a current-per-torque scale per joint (--prior
identified-current) against the data-only grey box (--prior data-only, what an arm without a description
gets), each alone and with NEXT on top, and ridge on hand features -- on the held-out pair
(Movement_No7_Acc_slow_Verify_Model_short, TEST; trained on the six training runs) and leave-one-run-out over
the six training runs (train on five, score the sixth). L1 [A]: mean over joints of mean |estimate| on free
motion (truth 0), as bench/bench_next_ur5.py.

    python bench/bench_urdf_ur5.py [--folds heldout,loro] [--priors identified-current,data-only]
                                   [--max-seconds 60] [--threads 1] [--out bench/out/urdf_ur5.json]

The arm is imported into a temporary $FACTR2_ARMS. The logs: $FACTR2_SHARED/data/ur5_kufieta2014 (default
../shared beside the checkout).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.bench_next_ur5 import EVAL_RUNS, TRAIN_RUNS

ROOT = Path(__file__).resolve().parents[1]

# the shared data folder: $FACTR2_SHARED (as tests/conftest.py), else ../shared beside the checkout
UR5 = Path(os.environ.get("FACTR2_SHARED", ROOT.parent / "shared")) / "data" / "ur5_kufieta2014"

METHODS = ("ridge", "prior", "next", "raw")


def import_ur5(folder: Path) -> None:
    os.environ["FACTR2_ARMS"] = str(folder)
    subprocess.run([sys.executable, "-m", "factr2_teleop.cli", "arm", "import",
                    str(ROOT / "hardware/arms/ur5.urdf"), "--name", "ur5", "--force", "--q-home",
                    "0,-1.57,1.57,-1.57,-1.57,0"], check=True,
                   stdout=subprocess.DEVNULL, env=dict(os.environ, PYTHONPATH=str(ROOT)))


def run(prior: str, train, evals, out: Path, max_seconds: float) -> dict:
    from calibration.next.train import TrainConfig
    from calibration.report import calibrate_from_logs

    cfg = TrainConfig(device="cpu", prior=prior, max_seconds=max_seconds)
    t0 = time.perf_counter()
    rep = calibrate_from_logs([UR5 / f"{r}.npz" for r in train], out, [UR5 / f"{r}.npz" for r in evals],
                              arm="ur5" if prior != "data-only" else None, cfg=cfg, plots=False)
    res = {"prior": rep["prior"], "wall_s": round(time.perf_counter() - t0, 1),
           "free_l1_A": {m: rep["methods"][m]["free_l1_mean"] for m in METHODS},
           "per_file": {f: {m: v["free_l1_mean"] for m, v in ms.items()} for f, ms in rep["files"].items()}}
    ck = json.loads((out / "next.json").read_text())
    if ck["model"].get("prior", {}).get("kind") == "identified-current":
        res["scale_A_per_Nm"] = ck["model"]["prior"]["scale"]
    return res


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--folds", default="heldout,loro")
    ap.add_argument("--priors", default="identified-current,data-only")
    ap.add_argument("--max-seconds", type=float, default=60.0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "bench/out/urdf_ur5.json"))
    args = ap.parse_args()
    if not UR5.is_dir():
        print(f"no UR5 logs at {UR5}")
        return 2
    import torch

    torch.set_num_threads(args.threads)
    tmp = Path(tempfile.mkdtemp(prefix="urdf_ur5_"))
    import_ur5(tmp / "arms")
    folds = []
    if "heldout" in args.folds:
        folds.append(("heldout", TRAIN_RUNS, EVAL_RUNS))
    if "loro" in args.folds:
        folds += [(f"loro:{r}", [x for x in TRAIN_RUNS if x != r], [r]) for r in TRAIN_RUNS]
    results: dict = {}
    outp = Path(args.out)
    outp.parent.mkdir(parents=True, exist_ok=True)
    for name, train, evals in folds:
        for prior in args.priors.split(","):
            r = run(prior, train, evals, tmp / f"{name.replace(':', '_')}_{prior}", args.max_seconds)
            results.setdefault(name, {})[prior] = r
            print(f"{name:48s} {prior:20s} " + " ".join(f"{m} {r['free_l1_A'][m]:.3f}" for m in METHODS)
                  + f"  ({r['wall_s']:.0f} s)", flush=True)
            outp.write_text(json.dumps(results, indent=1))
    loro = [v for k, v in results.items() if k.startswith("loro:")]
    if loro:
        for prior in args.priors.split(","):
            means = {m: sum(f[prior]["free_l1_A"][m] for f in loro) / len(loro) for m in METHODS}
            results.setdefault("loro_mean", {})[prior] = means
            print(f"{'leave-one-run-out mean':48s} {prior:20s} "
                  + " ".join(f"{m} {means[m]:.3f}" for m in METHODS))
    outp.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
