"""NEXT benchmarks.

1. Streaming estimator speed: NextEstimator.update (6 joints, H=50, 2x128 LSTM) vs a plain torch forward of
   the same model on the same 50-step window, same run, one thread; prints the ratio and the largest
   difference between the two outputs. `--checkpoint DIR/next.json`: the same on a trained checkpoint fed
   its held-out recording, in the mode the estimator picks (carried state when the training measured fading
   memory) and with exact windows, the physics prior included or not.
2. UR5 real logs (../shared/data/ur5_kufieta2014, current in A): train NEXT on the free-motion runs, score
   held-out runs (free motion: L1 vs 0, in A) against the ridge baseline and raw current; report the time to
   reach within 5 % of the best validation loss of the run (the run's best stands in for "converged" -- run
   with a large --max-seconds for a real convergence point).

3. Twin (SIMULATED, optional): `--twin-data DIR` = the data/ folder of a `factr2 calibrate --rig sim-piper`
   run (train.npz, heldout.npz, contact_eval.npz): train NEXT on train.npz once per `--twin-priors` entry
   (default: the paper's plain NEXT, then NEXT on the identified physics prior), score held-out free motion
   and the pushed contact replay against the disturbance observer and FILIC (ratios printed).

    python -m bench.bench_next [--threads 2] [--max-seconds 600] [--skip-train] [--checkpoint DIR/next.json]
                               [--twin-data DIR]
                               [--twin-priors none,identified]
Writes bench/out/next.json.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # the estimator runs on one core: no BLAS thread pool
import numpy as np  # noqa: E402
import torch  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
UR5 = ROOT.parent / "shared" / "data" / "ur5_kufieta2014"
TRAIN_RUNS = ["Movement_No1", "Movement_No2", "Movement_No3_Acc", "Movement_No4_Acc",
              "Movement_No5_Acc_slow_no_disturbance", "Movement_No6_Acc_slow_Verify_Model"]
EVAL_RUNS = ["Movement_No7_Acc_slow_Verify_Model_short", "TEST"]
DISTURBED = ["Movement_No5_Acc_slow_w_disturbance",
             "Movement_No7_Acc_slow_Verify_Model_short_with_disturbance"]


def bench_estimator(ticks: int = 2000) -> dict:
    from calibration.next.checkpoint import NextCheckpoint
    from calibration.next.data import Normalizer
    from calibration.next.estimator import NextEstimator
    from calibration.next.model import ModelConfig, NextModel

    torch.set_num_threads(1)
    torch.manual_seed(0)
    model = NextModel(ModelConfig(n_in=18, n_out=6)).eval()
    norm = Normalizer(np.zeros(18), np.ones(18), np.zeros(6), np.ones(6))
    ck = NextCheckpoint(model=model, normalizer=norm, arm="bench", joint_names=[f"j{i}" for i in range(6)],
                        units="N*m", inputs="q,qd,dq", rate_hz=100.0, x_min=np.full(18, -1e3),
                        x_max=np.full(18, 1e3))
    rng = np.random.default_rng(0)
    q = np.cumsum(rng.normal(0, 0.02, (ticks, 6)), 0)
    qd, tau = rng.normal(0, 0.5, (ticks, 6)), rng.normal(size=(ticks, 6))
    qc = q + rng.normal(0, 0.01, (ticks, 6))
    x = np.concatenate([q, qd, qc - q], 1).astype(np.float32)
    est = NextEstimator(ck)
    h = ck.history
    fast = np.empty((ticks, 6))
    t0 = time.perf_counter()
    for i in range(ticks):
        fast[i] = est.update(q[i], qd[i], qc[i], tau[i]).tau_f
    t_fast = (time.perf_counter() - t0) / ticks
    ref = np.full((ticks, 6), np.nan)
    t0 = time.perf_counter()
    with torch.no_grad():
        for i in range(h - 1, ticks):
            ref[i] = model(torch.from_numpy(x[i - h + 1:i + 1][None]))[0].numpy()
    t_torch = (time.perf_counter() - t0) / (ticks - h + 1)
    diff = float(np.nanmax(np.abs(fast[h - 1:] - ref[h - 1:])))
    # the same network on top of a physics prior (the Piper description): what the prior adds per tick
    from calibration.next.prior import description_prior

    with_prior = {**ck.__dict__, "arm": "piper", "prior": description_prior("piper")}
    est_p = NextEstimator(NextCheckpoint(**with_prior))
    t0 = time.perf_counter()
    for i in range(ticks):
        est_p.update(q[i], qd[i], qc[i], tau[i])
    t_prior = (time.perf_counter() - t0) / ticks
    out = {"estimator_ms": t_fast * 1e3, "torch_window_forward_ms": t_torch * 1e3,
           "speedup": t_torch / t_fast, "max_abs_diff": diff, "estimator_with_prior_ms": t_prior * 1e3}
    print(f"estimator {out['estimator_ms']:.3f} ms/tick, plain torch LSTM window forward "
          f"{out['torch_window_forward_ms']:.3f} ms -> {out['speedup']:.2f}x faster; max |diff| {diff:.2e}; "
          f"with the physics prior {t_prior * 1e3:.3f} ms/tick")
    return out


def bench_checkpoint(path: Path, ticks: int = 3000) -> dict:
    """The streaming estimator on a trained checkpoint (next.json of `factr2 calibrate --rig`), fed the
    held-out recording next to it (data/heldout.npz): per tick, in the mode the estimator picks and with
    the exact windows; the network alone vs a plain torch forward on the same windows (ratio, largest
    difference), and the whole estimate (physics prior included)."""
    from dataclasses import replace

    from calibration.next.checkpoint import load_checkpoint
    from calibration.next.data import make_inputs
    from calibration.next.estimator import NextEstimator

    torch.set_num_threads(1)
    ck = load_checkpoint(path)
    d = np.load(path.parent / "data" / "heldout.npz")
    n = min(ticks, len(d["t"]))
    q, qd, qc, tau, temp = (d[k][:n] for k in ("q", "qd", "q_cmd", "tau_m", "temperature"))

    def run(est) -> tuple[float, np.ndarray]:
        out = np.empty((n, len(ck.joint_names)))
        t0 = time.perf_counter()
        for i in range(n):
            out[i] = est.update(q[i], qd[i], qc[i], tau[i], temp[i]).tau_f
        return (time.perf_counter() - t0) / n, out

    h, norm = ck.history, ck.normalizer
    x = torch.from_numpy(norm.norm_x(make_inputs(q, qd, qc, ck.inputs)).astype(np.float32))
    ref = np.full((n, len(ck.joint_names)), np.nan)
    t0 = time.perf_counter()
    with torch.no_grad():
        for i in range(h - 1, n):
            ref[i] = ck.model(x[None, i - h + 1:i + 1])[0].numpy()
    t_torch = (time.perf_counter() - t0) / (n - h + 1)
    ref = ref * norm.y_std + norm.y_mean
    net = replace(ck, prior=None)
    auto = NextEstimator(net)
    rows = {}
    exact = (NextEstimator(net, carried=False), NextEstimator(ck, carried=False))
    for name, est_net, est_all in (("auto", auto, NextEstimator(ck)), ("exact", *exact)):
        t_net, f = run(est_net)
        t_all, _ = run(est_all)
        rows[name] = {"mode": est_net.mode, "network_ms": t_net * 1e3, "estimate_ms": t_all * 1e3,
                      "speedup_vs_torch": t_torch / t_net, "max_abs_diff": float(np.nanmax(np.abs(f - ref)))}
    out = {"checkpoint": str(path), "ticks": n, "torch_window_forward_ms": t_torch * 1e3, **rows,
           "carried_max_diff_at_training": (ck.metrics or {}).get("carried_max_diff"),
           "audits": auto.audits_done, "audit_max_diff": auto.audit_max_diff.tolist()}
    print(f"{path}: plain torch LSTM window forward {t_torch * 1e3:.3f} ms")
    for name, r in rows.items():
        print(f"  {name:5s} ({r['mode']}): network {r['network_ms']:.3f} ms/tick -> "
              f"{r['speedup_vs_torch']:.1f}x faster, max |diff| {r['max_abs_diff']:.2e} [{ck.units}]; "
              "whole estimate with prior "
              f"{r['estimate_ms']:.3f} ms/tick")
    print(f"  audits {auto.audits_done}, largest audit difference {auto.audit_max_diff.max():.2e} "
          f"[{ck.units}]")
    return out


def bench_ur5(threads: int, max_seconds: float, out_dir: Path) -> dict:
    from calibration.next.train import TrainConfig
    from calibration.report import calibrate_from_logs

    if not UR5.is_dir():
        print(f"UR5 logs not found at {UR5}: skipped")
        return {"skipped": True}
    curve = []

    def cb(p):
        curve.append((p.elapsed_s, p.val_loss))
        print(f"  epoch {p.epoch:3d}  val {p.val_loss:.4f}  best {p.best_val_loss:.4f}  {p.elapsed_s:6.0f} s",
              flush=True)

    cfg = TrainConfig(threads=threads, max_seconds=max_seconds, device="cpu")
    rep = calibrate_from_logs([UR5 / f"{r}.npz" for r in TRAIN_RUNS], out_dir,
                              [UR5 / f"{r}.npz" for r in EVAL_RUNS], [UR5 / f"{r}.npz" for r in DISTURBED],
                              cfg=cfg, callback=cb)
    best = min(v for _, v in curve)
    t5 = next(t for t, v in curve if v <= 1.05 * best)
    methods = ("next", "ridge", "raw")
    res = {"threads": threads, "train_seconds": rep["train_seconds"], "epochs": rep["epochs"],
           "data_minutes": rep["data_minutes"], "best_val_mse_normalized": best,
           "seconds_to_within_5pct_of_best": t5,
           "held_out_free_l1_A": {m: rep["methods"][m]["free_l1_mean"] for m in methods},
           "held_out_free_l1_A_per_joint": {m: rep["methods"][m]["free_l1"] for m in methods},
           "curve": curve}
    print(f"UR5 held-out free-motion L1 [A]: NEXT {res['held_out_free_l1_A']['next']:.3f}, ridge "
          f"{res['held_out_free_l1_A']['ridge']:.3f}, raw {res['held_out_free_l1_A']['raw']:.3f}; "
          f"{rep['epochs']} epochs in {rep['train_seconds']:.0f} s, within 5 % of best after {t5:.0f} s")
    return res


def bench_twin(data_dir: Path, threads: int, max_seconds: float, out_dir: Path, prior: str = "none") -> dict:
    from calibration.next.train import TrainConfig
    from calibration.report import calibrate_from_logs

    evals = [data_dir / "heldout.npz"] + [p for p in [data_dir / "contact_eval.npz"] if p.is_file()]
    curve = []
    cfg = TrainConfig(threads=threads, max_seconds=max_seconds, device="cpu", prior=prior)
    rep = calibrate_from_logs([data_dir / "train.npz"], out_dir, evals, arm="piper", cfg=cfg,
                              callback=lambda p: curve.append((p.elapsed_s, p.val_loss)))
    best = min(v for _, v in curve)
    m = rep["methods"]
    res = {"simulated": True, "prior": rep["prior"], "threads": threads,
           "train_seconds": rep["train_seconds"],
           "epochs": rep["epochs"],
           "data_minutes": rep["data_minutes"], "best_val_mse_normalized": best,
           "seconds_to_within_5pct_of_best": next(t for t, v in curve if v <= 1.05 * best),
           "free_l1_Nm": {k: v["free_l1_mean"] for k, v in m.items()},
           "contact_l1_Nm": {k: v["contact_l1_mean"] for k, v in m.items()}, "curve": curve}
    for kind in ("free", "contact"):
        d = res[f"{kind}_l1_Nm"]
        if d["next"] is not None and d["observer"]:
            res[f"{kind}_ratio_next_vs_observer"] = d["next"] / d["observer"]
    print(f"twin (SIMULATED, prior {rep['prior']}) " + ", ".join(f"{k} {json.dumps(res[k])}" for k in
                                          ("free_l1_Nm", "contact_l1_Nm") if k in res))
    print({k: v for k, v in res.items() if k.endswith("observer")})
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--max-seconds", type=float, default=600.0)
    ap.add_argument("--skip-train", action="store_true")
    ap.add_argument("--checkpoint", type=Path, help="next.json of a `factr2 calibrate --rig` run: time the "
                    "estimator on it, fed DIR/data/heldout.npz")
    ap.add_argument("--twin-data", type=Path, help="data/ folder of a factr2 calibrate --rig sim-piper run")
    ap.add_argument("--twin-priors", default="none,identified",
                    help="physics priors to train the twin part with (comma separated)")
    args = ap.parse_args()
    out = ROOT / "bench" / "out"
    out.mkdir(parents=True, exist_ok=True)
    results = {"estimator": bench_estimator()}
    if args.checkpoint is not None:
        results["checkpoint_estimator"] = bench_checkpoint(args.checkpoint)
    if not args.skip_train:
        results["ur5"] = bench_ur5(args.threads, args.max_seconds, out / "next_ur5")
        if args.twin_data is not None:
            results["twin"] = {p: bench_twin(args.twin_data, args.threads, args.max_seconds,
                                             out / f"next_twin_{p}", p) for p in args.twin_priors.split(",")}
    (out / "next.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
