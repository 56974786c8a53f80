"""`factr2 export lerobot RECORDING_OR_DIR... --out DIR`: recorded episodes as a LeRobotDataset v3.0
folder (state, tau_ext, action, images as mp4, the FIRST phase of every frame);
policies/export/export_lerobot.py. `factr2 export next-official CKPT --out DIR`: a NEXT checkpoint in the
official stack's layout (calibration/next/official.py)."""

from __future__ import annotations

import sys
from pathlib import Path

from hardware.errors import UserError
from hardware.recording import schemas as S
from policies.labels.label_flags import add_label_arguments, thresholds_arg

HELP = "export recorded episodes (with FIRST phases) as a LeRobotDataset v3.0 folder"


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="format", metavar="FORMAT", required=True)
    p = sub.add_parser("lerobot", help="LeRobotDataset v3.0: meta/, data/ parquet, videos/ mp4")
    p.add_argument("inputs", type=Path, nargs="+", metavar="RECORDING_OR_DIR")
    p.add_argument(
        "--out", type=Path, required=True, metavar="DIR", help="the dataset folder (must not exist)"
    )
    p.add_argument("--fps", type=int, default=None,
                   help="rows per second (default: the camera's rate in the rig file; no cameras: 30)")
    add_label_arguments(p)
    p.add_argument("--robot-type", default="", help="info.json robot_type (default: factr2)")
    p.add_argument("--lerobot-map", default=None, metavar="ROLE=KEY,...",
                   help="LeRobotDataset inputs: feature names over the defaults (docs/bringing_data.md)")
    p = sub.add_parser("next-official", help="a NEXT checkpoint in the official ROS 2 stack's layout "
                       "(model.pt, normalization.npz, metrics.json, config.yaml)")
    p.add_argument("checkpoint", type=Path, metavar="CKPT",
                   help="a `factr2 calibrate` checkpoint (next.json)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="the run folder (must not exist)")


def _next_official(args) -> int:
    from calibration.next.checkpoint import load_checkpoint
    from calibration.next.official import OFFICIAL_RATE_HZ, write_official

    if args.out.exists():
        raise UserError("output folder exists", where=str(args.out), fix="name a new --out folder")
    ck = load_checkpoint(args.checkpoint)
    write_official(ck, args.out)
    print(f"{args.out}: official NEXT layout, {len(ck.joint_names)} joints, history {ck.history} samples at "
          f"{ck.rate_hz:g} Hz, estimates in {ck.units}")
    if ck.rate_hz != OFFICIAL_RATE_HZ:
        print(f"warning: trained at {ck.rate_hz:g} Hz; the official recorder runs at {OFFICIAL_RATE_HZ:g} "
              f"Hz: calibrate with --rate-hz {OFFICIAL_RATE_HZ:g} to run it there", file=sys.stderr)
    return 0


def run(args) -> int:
    if args.format == "next-official":
        return _next_official(args)
    from policies.data.recordings import load_episodes
    from policies.export.export_lerobot import export_lerobot
    from policies.labels.labelling import load_next, resolve_thresholds

    given = thresholds_arg(args)
    if args.fps is not None and args.fps < 1:
        raise UserError(f"--fps must be >= 1, got {args.fps}")
    if args.out.exists():
        raise UserError("output folder exists", where=str(args.out), fix="name a new --out folder")
    episodes, arms = load_episodes(args.inputs, lerobot_map=args.lerobot_map)
    model = load_next(args.next) if args.next is not None else None
    th = resolve_thresholds(given, model, episodes, arms)
    info = export_lerobot(episodes, arms, args.out, th, model, args.fps, args.robot_type)
    for line in info["factr2/warnings"]:
        print(f"warning: {line}", file=sys.stderr)
    cams = [k.rsplit(".", 1)[-1] for k, f in info["features"].items() if f["dtype"] == "video"]
    extra = ", PRIVILEGED object state (SIMULATED)" if S.TASK_OBJECTS_FEATURE in info["features"] else ""
    print(
        f"{args.out}: LeRobotDataset {info['codebase_version']}, {info['total_episodes']} episodes, "
        f"{info['total_frames']} frames at {info['fps']} fps, "
        + (f"cameras {', '.join(cams)}" if cams else "state only (no cameras)") + extra
    )
    return 0
