"""`factr2 episodes list|show|trim|delete|merge`: manage recorded episodes (.mcap sessions, .npz logs)."""

from __future__ import annotations

from pathlib import Path

from hardware.recording import episodes as E

HELP = "list, show, trim, delete or merge recorded episodes"


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    p = sub.add_parser("list", help="one line per episode: outcome, duration, samples, contact share")
    p.add_argument("path", type=Path, help="a folder of recordings (.mcap, .npz) or one file")
    p = sub.add_parser("show", help="metadata, topics, cameras, episodes and events of one recording")
    p.add_argument("path", type=Path)
    p = sub.add_parser("trim", help="keep only [--start, --end] seconds of one episode")
    p.add_argument("path", type=Path)
    p.add_argument("--episode", type=int, required=True)
    p.add_argument("--start", type=float, default=0.0, help="seconds after the episode start (default 0)")
    p.add_argument("--end", type=float, default=None,
                   help="seconds after the episode start (default: its end)")
    p.add_argument("-o", "--output", type=Path, default=None, help="write here instead of in place")
    p = sub.add_parser("delete", help="remove one episode from a recording")
    p.add_argument("path", type=Path)
    p.add_argument("--episode", type=int, required=True)
    p.add_argument("-o", "--output", type=Path, default=None, help="write here instead of in place")
    p = sub.add_parser("merge", help="concatenate recordings (files or folders) into one")
    p.add_argument("path", type=Path, nargs="+")
    p.add_argument("-o", "--output", type=Path, required=True)


def run(args) -> int:
    if args.action == "list":
        print(E.format_rows(E.list_episodes(args.path)))
    elif args.action == "show":
        print(E.show(args.path))
    elif args.action == "trim":
        print(E.trim_episode(args.path, args.episode, args.start, args.end, args.output).summary())
    elif args.action == "delete":
        print(E.delete_episode(args.path, args.episode, args.output).summary())
    elif args.action == "merge":
        print(E.merge(args.path, args.output).summary())
    return 0
