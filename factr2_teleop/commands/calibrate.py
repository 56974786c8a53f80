"""`factr2 calibrate`: train NEXT (learned free-space inverse dynamics) and compare it with the baselines.

From existing logs (plain .npz, hardware/recording/plain_log.py):
    factr2 calibrate --from-logs A.npz B.npz --eval C.npz --out runs/cal1 [--arm piper]
With logs that carry current and no torque constant, every estimate is in A.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from hardware.errors import UserError

HELP = "train NEXT external-torque estimation from free-motion logs and compare it with baselines"
HELDOUT_BLOCK_S = 20.0  # held-out free motion comes in blocks of this length [s]
CONTACT_EVAL_S = 300.0  # pushed replay scored for contact L1 [s]: the paper's 5 min of held-out contact data


def add_arguments(p) -> None:
    p.add_argument("--from-logs", nargs="+", metavar="LOG.npz", help="free-motion plain logs to train on")
    p.add_argument("--eval", nargs="*", default=[], metavar="LOG.npz",
                   help="held-out logs: free motion (scored vs 0) unless they carry contact/tau_ext_true")
    p.add_argument("--eval-unlabeled", nargs="*", default=[], metavar="LOG.npz",
                   help="held-out logs with unknown contact (estimates and plots only, no scores)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (checkpoint, report, plots)")
    p.add_argument("--arm", help="arm the logs come from (hardware/arms name): enables FILIC, observer")
    p.add_argument("--rig", help="record free motion on this rig (name or TOML; sim-* rigs run the twin)")
    p.add_argument("--follower", help="follower of the rig to calibrate (default: the first)")
    p.add_argument("--minutes", type=float, default=10.0, help="length of the recorded free motion [min]")
    p.add_argument("--twin-effect", metavar="MOD:FN", help="twin effect hook (simulated rigs only)")
    p.add_argument("--heldout-frac", type=float, default=0.15,
                   help="fraction of the recorded motion kept for evaluation, as 20 s blocks spread over the "
                        "run (default 0.15)")
    p.add_argument("--contact-eval-s", type=float, default=CONTACT_EVAL_S,
                   help="simulated rigs: length [s] of an extra held-out replay with scripted pushes "
                        "(ground truth logged) used to score contact L1; 0 to skip (default "
                        f"{CONTACT_EVAL_S:.0f}, the paper's 5 minutes of held-out contact data)")
    p.add_argument("--min-minutes", type=float, default=2.0,
                   help="keep the data and train when an unexpected contact stops the replay after at least "
                        "this long [min] (default 2)")
    p.add_argument("--rate-hz", type=float, default=100.0, help="resampling rate [Hz] (default 100)")
    p.add_argument("--arch", choices=("lstm", "gru", "mlp"), default="lstm", help="network (ablation)")
    p.add_argument("--history", type=int, default=50, help="window length H in samples (default 50)")
    p.add_argument("--inputs", choices=("q", "q,qd", "q,qd,dq"), default="q,qd,dq", help="inputs (ablation)")
    p.add_argument("--prior", choices=("auto", "none", "description", "identified"), default="auto",
                   help="physics prior under the network: identified = the arm description corrected by "
                        "least squares on this data (+ friction, thermal drift of the torque constant, "
                        "ripple); description = as described; none = the paper's plain NEXT; auto (default) "
                        "= identified when the arm is known and torque is in N*m")
    p.add_argument("--max-epochs", type=int, default=400)
    p.add_argument("--max-seconds", type=float, default=math.inf, help="stop training after this long")
    p.add_argument("--device", default="auto", help="torch device: auto (cuda if present), cpu, cuda")
    p.add_argument("--observer-gain", type=float, default=50.0, help="momentum observer gain K_o [1/s]")
    p.add_argument("--no-plots", action="store_true")


def _run_on_rig(args, cfg) -> int:
    """Record free motion on a rig, then train and evaluate as --from-logs does (last part held out)."""
    import json

    from tqdm import tqdm

    from calibration.next.collect import ContactStop, collect_free_motion
    from calibration.report import calibrate_from_logs
    from calibration.trajectories import arm_coverage_trajectory
    from hardware.recording.plain_log import save_plain_log
    from hardware.rigs.rig import load_rig
    from hardware.sim import open_rig

    rig = load_rig(args.rig)
    spec = rig.device(args.follower) if args.follower else rig.followers[0]
    if not args.minutes > 0:
        raise UserError(f"--minutes {args.minutes} must be positive", where="--minutes",
                        fix="e.g. --minutes 10")
    if not 0.0 < args.heldout_frac < 0.9:
        raise UserError(f"--heldout-frac {args.heldout_frac} out of range", where="--heldout-frac",
                        fix="use a value between 0 and 0.9, e.g. 0.15")
    traj = arm_coverage_trajectory(spec.arm, args.minutes, args.rate_hz,
                                   scene=rig.twin.scene if rig.simulated else "table")
    out = Path(args.out)
    (out / "data").mkdir(parents=True, exist_ok=True)
    show = sys.stderr.isatty()
    bar = tqdm(total=round(traj.duration_s), unit="s", desc=f"free motion on {rig.name}/{spec.name}",
               disable=not show)

    def progress(done_s: float, total_s: float) -> None:
        bar.total = round(total_s)
        bar.n = round(done_s)
        bar.refresh()

    contact_eval = None
    with open_rig(rig, clock="lockstep" if rig.simulated else "realtime", effect=args.twin_effect) as session:
        try:
            run = collect_free_motion(session, spec.name, traj, progress=progress)
        except ContactStop as e:
            run = e.run
            keep = 0 if run is None else max(0, len(run.t) - int(2.0 * args.rate_hz))  # drop the last 2 s
            if keep < args.min_minutes * 60.0 * args.rate_hz:
                raise
            for k in ("t", "q", "qd", "q_cmd", "tau_m", "current", "temperature", "tau_ext_true", "contact"):
                setattr(run, k, getattr(run, k)[:keep])
            run.stopped = f"contact: {e.what}"
            minutes = keep / args.rate_hz / 60.0
            print(f"warning: {e.what}; training on the {minutes:.1f} min recorded before it", file=sys.stderr)
        if rig.simulated and args.contact_eval_s > 0:
            contact_eval = record_pushed_replay(session, spec, args.contact_eval_s, args.rate_hz, seed=1)
    bar.close()
    arrays = run.arrays()
    n = len(arrays["t"])
    held_mask = heldout_blocks(n, args.heldout_frac, int(round(HELDOUT_BLOCK_S * args.rate_hz)))
    per_sample = {k: v for k, v in arrays.items() if v.ndim >= 1 and len(v) == n}
    fixed = {k: v for k, v in arrays.items() if k not in per_sample}
    save_plain_log(out / "data" / "free_motion.npz", **arrays)
    data = out / "data"
    train = save_plain_log(data / "train.npz", **{k: v[~held_mask] for k, v in per_sample.items()}, **fixed)
    held = save_plain_log(data / "heldout.npz", **{k: v[held_mask] for k, v in per_sample.items()}, **fixed)
    evals = [held]
    if contact_eval is not None:
        evals.append(save_plain_log(data / "contact_eval.npz", **contact_eval.arrays()))
    report = calibrate_from_logs([train], out, evals, arm=spec.arm, cfg=cfg, rate_hz=args.rate_hz,
                                 observer_gain=args.observer_gain, plots=not args.no_plots)
    report.update(rig=rig.name, follower=spec.name, simulated=rig.simulated,
                  collision_checked=traj.collision_checked, stopped=run.stopped or None)
    (out / "report.json").write_text(json.dumps(report, indent=1))
    _print_summary(report, out)
    return 0


def heldout_blocks(n: int, frac: float, block: int) -> np.ndarray:
    """(n,) bool: which samples are held out -- every k-th block of `block` samples (k = round(1 / frac),
    the first block always trains). Blocks spread over the whole recording, so the held-out part has every
    phase of the trajectory (slow, multi-joint, fast); a held-out tail would be the fast phase only, which
    the model never saw. Runs shorter than k blocks get blocks of n // k samples. The time gaps left in
    both files make resampling split them into segments, so no training window ever spans a cut."""
    k = max(2, int(round(1.0 / frac)))
    block = max(1, min(block, n // k))  # a short run gets shorter blocks, so something is held out
    idx = np.arange(n) // block
    return (idx % k) == k - 1


def record_pushed_replay(session, spec, seconds: float, rate_hz: float, seed: int = 1):
    """SIMULATED: replay a fresh coverage trajectory (seed >= 1: not the training data's) while the twin
    pushes links 3-6 (10-40 N, 0.5-1.5 s, one every ~3 s); the log carries the twin's ground truth (the mean
    over each sample period). The calibration's contact evaluation is seed 1; other seeds give independent
    runs (bench/tune_next_filter.py)."""
    from calibration.next.collect import Push, collect_free_motion
    from calibration.trajectories import arm_coverage_trajectory

    traj = arm_coverage_trajectory(spec.arm, seconds / 60.0, rate_hz, scene=session.rig.twin.scene, seed=seed)
    rng = np.random.default_rng(seed)
    pushes, t = [], 2.0
    while t < traj.duration_s - 2.0:
        d = rng.uniform(0.5, 1.5)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        pushes.append(Push(t, f"link{rng.integers(3, 7)}", tuple(rng.uniform(10, 40) * direction), d))
        t += d + rng.uniform(1.0, 3.0)
    return collect_free_motion(session, spec.name, traj, pushes=pushes)


def _print_summary(report: dict, out: Path) -> None:
    u = report["units"]
    sim = " (SIMULATED twin)" if report.get("simulated") else ""
    print(f"trained on {report['data_minutes']:.1f} min{sim} in {report['train_seconds']:.0f} s "
          f"({report['device']}); estimates in {u}; physics prior: {report.get('prior', 'none')}",
          file=sys.stderr)
    for m, v in report["methods"].items():
        free, con = v["free_l1_mean"], v["contact_l1_mean"]
        print(f"  {m:9s} free L1 {'--' if free is None else f'{free:.4f}'}  "
              f"contact L1 {'--' if con is None else f'{con:.4f}'} [{u}]")
    print(f"wrote {out / 'report.md'}")


def _check_files(paths, flag: str) -> list[Path]:
    out = []
    for p in paths:
        path = Path(p)
        if not path.is_file():
            raise UserError("log file not found", where=str(path), fix=f"check the paths given to {flag}")
        out.append(path)
    return out


def run(args) -> int:
    from calibration.next.train import TrainConfig
    from calibration.report import calibrate_from_logs

    if args.rig:
        return _run_on_rig(args, TrainConfig(arch=args.arch, history=args.history, inputs=args.inputs,
                                             max_epochs=args.max_epochs, max_seconds=args.max_seconds,
                                             device=args.device, prior=args.prior))
    if not args.from_logs:
        raise UserError("nothing to train on", where="factr2 calibrate",
                        fix="pass --from-logs FREE_MOTION.npz ... (plain logs)")
    if args.history < 2:
        raise UserError(f"--history {args.history} is too short", where="--history", fix="use 10, 25 or 50")
    train_paths = _check_files(args.from_logs, "--from-logs")
    eval_paths = _check_files(args.eval, "--eval")
    unlabeled = _check_files(args.eval_unlabeled, "--eval-unlabeled")
    cfg = TrainConfig(arch=args.arch, history=args.history, inputs=args.inputs, max_epochs=args.max_epochs,
                      max_seconds=args.max_seconds, device=args.device, prior=args.prior)
    try:
        report = calibrate_from_logs(train_paths, args.out, eval_paths, unlabeled, arm=args.arm, cfg=cfg,
                                     rate_hz=args.rate_hz, observer_gain=args.observer_gain,
                                     plots=not args.no_plots)
    except ValueError as e:  # too little data for one window, etc.
        raise UserError(str(e), where="factr2 calibrate", fix="give longer free-motion logs") from None
    _print_summary(report, Path(args.out))
    return 0
