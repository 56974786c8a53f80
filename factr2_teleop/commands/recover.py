"""`factr2 recover FILE`: rewrite a truncated recording (recorder killed, disk full) into a valid MCAP."""

from __future__ import annotations

from pathlib import Path

from hardware.recording.recover import recover, recovered_path

HELP = "rewrite a truncated or damaged .mcap recording into a valid one"


def add_arguments(parser) -> None:
    parser.add_argument("file", type=Path, help="the .mcap recording to recover")
    parser.add_argument("-o", "--output", type=Path, default=None,
                        help="output file (default: FILE with .recovered.mcap)")
    parser.add_argument("--in-place", action="store_true",
                        help="replace FILE (atomically, once the recovered file is complete)")


def run(args) -> int:
    report = recover(args.file, args.output, in_place=args.in_place)
    print(report.summary())
    if not args.in_place and args.output is None:
        print(f"{args.file} stays as it was; folder readers (episodes list, train, export, the app) now use "
              f"{recovered_path(args.file).name} in its place")
    for w in report.warnings:
        print(f"warning: {w}")
    return 0
