"""`factr2 recover FILE`: rewrite a truncated recording (recorder killed, disk full) into a valid MCAP, and
make a session summary beside it (`factr2 collect`'s or `factr2 rollout --json`'s) say what the rewritten
file holds, as the session's own read-back does (session/read_back.py reread_summary)."""

from __future__ import annotations

import json
import os
from pathlib import Path

from hardware.errors import UserError
from hardware.recording.recover import recover, recovered_path

HELP = "rewrite a truncated or damaged .mcap recording into a valid one (and its session summary)"


def add_arguments(parser) -> None:
    parser.add_argument("file", type=Path, help="the .mcap recording to recover")
    parser.add_argument("-o", "--output", type=Path, default=None,
                        help="output file (default: FILE with .recovered.mcap)")
    parser.add_argument("--in-place", action="store_true",
                        help="replace FILE (atomically, once the recovered file is complete)")
    summary = parser.add_mutually_exclusive_group()
    summary.add_argument("--summary", type=Path, default=None,
                         help="the session summary JSON to update (default: every JSON beside FILE whose "
                              "'recording' names it; FILE's stem + .json is collect's)")
    summary.add_argument("--no-summary", action="store_true", help="leave every summary as it is")


def find_summaries(mcap: Path) -> list[Path]:
    """The session summaries beside `mcap`: JSON files in its folder whose "recording" names it (collect's is
    its stem + ".json"). Another JSON there that cannot be read is not one; that stem + ".json" must be."""
    own = mcap.with_suffix(".json")
    found = []
    for path in sorted(mcap.parent.glob("*.json")):
        try:
            rec = json.loads(path.read_text()).get("recording")
        except (OSError, ValueError, AttributeError):
            rec = None
        if path == own or (isinstance(rec, str) and Path(rec).name == mcap.name):
            found.append(path)
    return found


def load_summary(path: Path) -> dict:
    """A summary JSON, checked to be a session's (read_back.summary_episodes); UserError (one line) if not."""
    from factr2_teleop.session.read_back import summary_episodes

    try:
        summary = json.loads(path.read_text())
    except OSError as e:
        raise UserError(f"cannot read the summary ({e.strerror or e}): nothing recovered", where=str(path),
                        fix="check the path, or pass --no-summary") from None
    except ValueError as e:
        raise UserError(f"the summary is not JSON ({e}): nothing recovered", where=str(path),
                        fix="restore it, or pass --no-summary to recover the file alone") from None
    summary_episodes(summary, str(path))
    return summary


def write_summary(path: Path, summary: dict) -> None:
    """Write `summary` over `path` atomically (a temporary file renamed over it once complete)."""
    tmp = path.with_name(path.name + f".tmp-{os.getpid()}")
    try:
        tmp.write_text(json.dumps(summary, indent=1, default=float))
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise UserError(f"cannot write the summary ({e.strerror or e}); the recovered file is complete",
                        where=str(path), fix="check free space and permissions, then run it again") from None


def run(args) -> int:
    from factr2_teleop.session.read_back import reread_summary

    if not args.file.is_file():
        raise UserError("no such recording", where=str(args.file), fix="check the path")
    paths = ([] if args.no_summary else [args.summary] if args.summary is not None
             else find_summaries(args.file))
    summaries = [(p, load_summary(p)) for p in paths]  # all read before anything is written
    report = recover(args.file, args.output, in_place=args.in_place)
    print(report.summary())
    if not args.in_place and args.output is None:
        print(f"{args.file} stays as it was; folder readers (episodes list, train, export, the app) now use "
              f"{recovered_path(args.file).name} in its place")
    for w in report.warnings:
        print(f"warning: {w}")
    for path, summary in summaries:
        said = reread_summary(summary, report.dst)
        if report.dst != args.file:  # the summary now describes the recovered copy (the file stays as it was)
            rec = summary.get("recording")
            beside = isinstance(rec, str) and report.dst.parent.resolve() == args.file.parent.resolve()
            summary["recording"] = str(Path(rec).with_name(report.dst.name)) if beside else str(report.dst)
            said += f"; recording -> {summary['recording']}"
        write_summary(path, summary)
        print(f"summary {path}: {said}")
    if not summaries and not args.no_summary:
        print(f"no session summary beside {args.file} names it: none updated")
    return 0
