"""`factr2 tui`: the terminal app (rig status, NEXT calibration wizard, bilateral teleop, recording,
episodes). See docs/tui.md."""

from __future__ import annotations

import argparse

from calibration.estimators import FEEDBACK_MODES
from hardware.errors import UserError

HELP = ("terminal app: rig status, calibration wizard, force-feedback teleop and recording, episodes, "
        "FIRST training, policy rollout")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--rig", default="sim-piper", help="built-in rig name or path to a rig .toml (default sim-piper)"
    )
    p.add_argument(
        "--out",
        default="factr2_out",
        metavar="DIR",
        help="folder for recordings/ and calibration/ (default ./factr2_out)",
    )
    p.add_argument("--recordings", default=None, metavar="DIR",
                   help="recordings folder to list, train on and record into (default OUT/recordings), e.g. "
                   "a `factr2 collect --out` folder")
    p.add_argument("--runs", default=None, metavar="DIR",
                   help="training runs folder, or one `factr2 train --out` run (default OUT/runs)")
    p.add_argument("--connect", action="store_true", help="connect to the rig at start")
    p.add_argument(
        "--clock",
        choices=("auto", "lockstep", "realtime"),
        default="auto",
        help="simulated rigs: lockstep (default, deterministic) or realtime; real rigs: realtime",
    )
    p.add_argument(
        "--pace",
        type=float,
        default=1.0,
        help="lockstep only: most simulated seconds per wall second (0 = as fast as possible)",
    )
    p.add_argument("--rate", type=float, default=500.0, help="teleop loop rate [Hz] (default 500)")
    p.add_argument(
        "--feedback",
        choices=FEEDBACK_MODES,
        help="initial feedback mode (default: ground_truth on twins, dob on real rigs)",
    )
    p.add_argument(
        "--cal-minutes",
        type=float,
        default=10.0,
        help="calibration replay length [min] (default 10, the paper's amount; [ and ] change it)",
    )
    p.add_argument("--light", action="store_true", help="light colour theme (meaning never rests on colour)")
    p.add_argument("--cal-epochs", type=int, default=400, help="most NEXT training epochs (default 400)")


def run(args) -> int:
    from factr2_teleop.session.pairs import modes_for
    from factr2_teleop.tui.app import Factr2App
    from factr2_teleop.tui.runtime import RigRuntime

    if not args.rate > 0:
        raise UserError(f"--rate {args.rate} must be > 0", where="--rate", fix="use e.g. 500")
    if not args.cal_minutes > 0 or args.cal_epochs < 1:
        raise UserError(
            "calibration length and epochs must be positive",
            where="--cal-minutes/--cal-epochs",
            fix="use e.g. --cal-minutes 0.5 --cal-epochs 20",
        )
    if args.pace < 0:
        raise UserError(f"--pace {args.pace} is negative", where="--pace", fix="use 1 (real time) or 0")
    from factr2_teleop.tui.folders import check_folder

    folders = {k: check_folder(v, k, where=f"--{k}") if v is not None else None
               for k, v in (("recordings", args.recordings), ("runs", args.runs))}
    runtime = RigRuntime(args.rig, clock=args.clock, pace=args.pace)  # ConfigError for a bad rig: one line
    if args.feedback is not None and args.feedback not in modes_for(runtime.rig):
        raise UserError(
            f"{args.feedback} feedback exists only on simulated rigs",
            where="--feedback",
            fix="use dob, pp or next",
        )
    app = Factr2App(
        runtime,
        out_dir=args.out,
        rate_hz=args.rate,
        cal_minutes=args.cal_minutes,
        cal_epochs=args.cal_epochs,
        connect=args.connect,
        mode=args.feedback,
        light=args.light,
        recordings_dir=folders["recordings"],
        runs_dir=folders["runs"],
    )
    try:
        app.run()
    finally:
        app.shutdown_all()  # whatever happened in the UI, the arms end safe
    return 0
