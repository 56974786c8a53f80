"""`factr2 calibrate`: train NEXT (learned free-space inverse dynamics) and compare it with the baselines.

From existing logs (plain .npz, hardware/recording/plain_log.py, or MCAP recordings: one run per episode):
    factr2 calibrate --from-logs A.npz B.npz --eval C.npz --out runs/cal1 [--arm piper]
With logs that carry current and no torque constant, every estimate is in A. Logs without q_cmd train on
(q, q_dot); corrupt rows are dropped with a warning (calibration/next/logs.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from calibration.next.priors import PRIOR_KINDS
from calibration.next.train import TRAIN_BUDGET_S, TrainConfig
from calibration.pipeline import CONTACT_EVAL_S, HELDOUT_FRAC, MIN_MINUTES, OBSERVER_GAIN
from hardware.errors import UserError

HELP = "train NEXT external-torque estimation from free-motion logs and compare it with baselines"


def add_arguments(p) -> None:
    p.add_argument("--from-logs", nargs="+", metavar="LOG", help="free-motion logs to train on: plain .npz "
                   "logs, .mcap recordings (a --rig run's data/calibration.mcap) or the official NEXT H5 "
                   "files (FILE.h5, FILE.h5::ARM for one arm of several)")
    p.add_argument("--eval", nargs="*", default=[], metavar="LOG.npz",
                   help="held-out logs: free motion (scored vs 0) unless they carry contact/tau_ext_true")
    p.add_argument("--eval-unlabeled", nargs="*", default=[], metavar="LOG.npz",
                   help="held-out logs with unknown contact (estimates and plots only, no scores)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (checkpoint, report, plots)")
    p.add_argument("--arm", help="arm the logs come from (hardware/arms name): enables FILIC, observer")
    p.add_argument("--joint-map", metavar="LOG=ARM,...",
                   help="with --from-logs: which arm joint each log joint is, when the names differ by more "
                        "than a common prefix/suffix or come in another order")
    p.add_argument("--rig", help="record free motion on this rig (name or TOML; sim-* rigs run the twin)")
    p.add_argument("--follower", help="follower of the rig to calibrate (default: the first)")
    p.add_argument("--minutes", type=float, default=10.0, help="length of the recorded free motion [min]")
    p.add_argument("--twin-effect", metavar="MOD:FN", help="twin effect hook (simulated rigs only)")
    p.add_argument("--heldout-frac", type=float, default=HELDOUT_FRAC,
                   help="fraction of the recorded motion kept for evaluation, as 20 s blocks spread over the "
                        f"run (default {HELDOUT_FRAC:g})")
    p.add_argument("--contact-eval-s", type=float, default=CONTACT_EVAL_S,
                   help="simulated rigs: length [s] of an extra held-out replay with scripted pushes "
                        "(ground truth logged) used to score contact L1; 0 to skip (default "
                        f"{CONTACT_EVAL_S:.0f}, the paper's 5 minutes of held-out contact data)")
    p.add_argument("--min-minutes", type=float, default=MIN_MINUTES,
                   help="keep the data and train when an unexpected contact stops the replay after at least "
                        "this long [min] (default 2)")
    p.add_argument("--rate-hz", type=float, default=100.0, help="resampling rate [Hz] (default 100)")
    p.add_argument("--arch", choices=("lstm", "gru", "mlp"), default="lstm", help="network (ablation)")
    p.add_argument("--history", type=int, default=50, help="window length H in samples (default 50)")
    p.add_argument("--inputs", choices=("q", "q,qd", "q,qd,dq"), default="q,qd,dq", help="inputs (ablation)")
    p.add_argument("--hidden", type=int, default=TrainConfig.hidden,
                   help=f"LSTM width (default {TrainConfig.hidden}; the paper's is 128)")
    p.add_argument("--prior", choices=("auto", *PRIOR_KINDS), default="auto",
                   help="physics prior under the network: identified = the arm description corrected "
                        "by least squares on this data (+ friction, thermal drift of the torque constant, "
                        "ripple); identified-current = the same for logs in A, with a current-per-torque "
                        "scale per joint; description = as described; data-only = a grey box fitted by ridge "
                        "without any description (gravity-, inertia-, Coriolis-like functions + friction); "
                        "none = the paper's plain NEXT; auto (default) = identified when the arm is known "
                        "(identified-current for logs in A), else data-only")
    p.add_argument("--max-epochs", type=int, default=400)
    p.add_argument("--max-seconds", type=float, default=TRAIN_BUDGET_S,
                   help=f"training budget [s] (default {TRAIN_BUDGET_S:g}; it usually stops earlier, when "
                        "the validation loss stops improving by 1 %% per 5 epochs; inf: no budget)")
    p.add_argument("--device", default="auto", help="torch device: auto (cuda if present), cpu, cuda")
    p.add_argument("--observer-gain", type=float, default=OBSERVER_GAIN,
                   help="momentum observer gain K_o [1/s]")
    p.add_argument("--no-plots", action="store_true")


def _run_on_rig(args, train_cfg) -> int:
    """Record free motion on a rig, then train and evaluate (calibration.pipeline, as the terminal app)."""
    from tqdm import tqdm

    from calibration.pipeline import CalibrationConfig, calibrate_rig
    from hardware.connect import open_rig
    from hardware.rigs.rig import load_rig

    rig = load_rig(args.rig)
    spec = rig.device(args.follower) if args.follower else rig.followers[0]
    cfg = CalibrationConfig(minutes=args.minutes, rate_hz=args.rate_hz, heldout_frac=args.heldout_frac,
                            contact_eval_s=args.contact_eval_s, min_minutes=args.min_minutes, train=train_cfg,
                            observer_gain=args.observer_gain, plots=not args.no_plots)
    cfg.check()
    bar = tqdm(total=round(args.minutes * 60), unit="s", desc=f"free motion on {rig.name}/{spec.name}",
               disable=not sys.stderr.isatty())

    def progress(done_s: float, total_s: float) -> None:
        bar.total = round(total_s)
        bar.n = round(done_s)
        bar.refresh()

    def say(text: str) -> None:
        print(text, file=sys.stderr)

    with open_rig(rig, clock="lockstep" if rig.simulated else "realtime", effect=args.twin_effect) as session:
        report = calibrate_rig(session, spec, args.out, cfg, progress=progress, say=say)
    bar.close()
    _print_summary(report, Path(args.out))
    return 0


def summary_lines(report: dict) -> list[str]:
    """What `factr2 calibrate` prints: training, every method's held-out L1, what the network adds."""
    u = report["units"]
    sim = " (SIMULATED twin)" if report.get("simulated") else ""
    t5 = report.get("train_seconds_to_within_5pct")
    lines = [f"trained on {report['data_minutes']:.1f} min{sim} in {report['train_seconds']:.0f} s "
             f"({report['device']}, {report.get('threads')} thread(s); within 5 % of the final validation "
             f"loss after {'--' if t5 is None else f'{t5:.0f}'} s; stopped: "
             f"{report.get('train_stop') or '--'}); "
             f"inputs {report.get('inputs')}; estimates in {u}; physics prior: {report.get('prior', 'none')}"]
    for m, v in report["methods"].items():
        free, con = v["free_l1_mean"], v["contact_l1_mean"]
        lines.append(f"  {m:9s} free L1 {'--' if free is None else f'{free:.4f}'}  "
                     f"contact L1 {'--' if con is None else f'{con:.4f}'} [{u}]")
    adds = report.get("network_adds") or {}
    base = "the prior" if adds.get("baseline") == "prior" else "the raw signal (no prior)"
    for kind in ("free", "contact"):
        a = adds.get(kind)
        if a:
            per = " ".join(f"{g:+.3f}" for g in a["gain"])
            lines.append(f"  the network over {base}, held-out {kind}: L1 {np.mean(a['prior_l1']):.4f} -> "
                         f"{np.mean(a['next_l1']):.4f} [{u}] (x{a['ratio_mean']:.2f}); gain per joint {per}")
    gate = report.get("network_gate")
    if gate is not None:
        lines.append("  share of the network's correction kept per joint (fitted on runs it never saw): "
                     + " ".join(f"{g:.2f}" for g in gate))
    return lines


def _print_summary(report: dict, out: Path) -> None:
    for line in summary_lines(report):
        print(line, file=sys.stderr)
    print(f"wrote {out / 'report.md'}")


def _check_files(paths, flag: str) -> list[Path]:
    out = []
    for p in paths:
        path = Path(p)
        if not Path(str(p).rsplit("::", 1)[0]).is_file():  # FILE.h5::ARM: an arm of an official H5 file
            raise UserError("log file not found", where=str(path), fix=f"check the paths given to {flag}")
        out.append(path)
    return out


def run(args) -> int:
    from calibration.report import calibrate_from_logs

    if args.rig:
        return _run_on_rig(args, TrainConfig(arch=args.arch, history=args.history, inputs=args.inputs,
                                             hidden=args.hidden,
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
    cfg = TrainConfig(arch=args.arch, history=args.history, inputs=args.inputs, hidden=args.hidden,
                      max_epochs=args.max_epochs,
                      max_seconds=args.max_seconds, device=args.device, prior=args.prior)
    try:
        report = calibrate_from_logs(train_paths, args.out, eval_paths, unlabeled, arm=args.arm, cfg=cfg,
                                     rate_hz=args.rate_hz, observer_gain=args.observer_gain,
                                     plots=not args.no_plots, say=lambda s: print(s, file=sys.stderr),
                                     joint_map=args.joint_map)
    except ValueError as e:  # too little data for one window, etc.
        raise UserError(str(e), where="factr2 calibrate", fix="give longer free-motion logs") from None
    _print_summary(report, Path(args.out))
    return 0
