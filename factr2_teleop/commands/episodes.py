"""`factr2 episodes list|show|trim|delete|merge|phases|import`: manage recorded episodes (.mcap sessions, .npz
logs; list and show read LeRobotDataset folders too); `phases` labels them free / pre-contact / contact for
FIRST (policies.labels.labelling); `import gello DIR` turns GELLO's saves into a recording."""

from __future__ import annotations

from pathlib import Path

from hardware.recording import episodes as E
from policies.labels.label_flags import add_label_arguments, thresholds_arg

HELP = "list, show, trim, delete, merge, phase-label or import (GELLO) recorded episodes"


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    p = sub.add_parser("list", help="one line per episode: outcome, duration, samples, contact share")
    p.add_argument("path", type=Path, help="a folder of recordings (.mcap, .npz), one file, or a "
                   "LeRobotDataset folder")
    _lerobot_map(p)
    p = sub.add_parser("show", help="metadata, topics, cameras, episodes and events of one recording")
    p.add_argument("path", type=Path)
    _lerobot_map(p)
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
    p = sub.add_parser("import", help="another tool's saves as one recording: gello (per-step pickles)")
    p.add_argument("format", choices=("gello",))
    p.add_argument("path", type=Path, metavar="DIR", help="an episode folder, or a folder of them")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.mcap", help="the recording to write")
    p.add_argument("--rate", type=float, default=None, help="steps per second when step files are "
                   "numbered rather than timed (GELLO's --hz) [Hz]")
    p.add_argument("--task", default="", help="task name for episodes that do not say one")
    p = sub.add_parser("phases", help="FIRST phase labels: per-episode shares of free / pre-contact / "
                       "contact and a PNG per episode (tau_ext with the phases shaded)")
    p.add_argument("path", type=Path, nargs="+", help="recordings (.mcap) or folders of them")
    add_label_arguments(p)
    p.add_argument("--out", type=Path, default=None,
                   help="folder for the PNGs (default: phases/ beside the first recording)")
    _lerobot_map(p)


def _lerobot_map(p) -> None:
    p.add_argument("--lerobot-map", default=None, metavar="ROLE=KEY,...",
                   help="LeRobotDataset folders: feature names over the defaults (docs/bringing_data.md)")


def _converted(path: Path, args) -> Path:
    """A LeRobotDataset folder -> its converted recording (hardware/importers/lerobot.py); else path."""
    from hardware.importers.lerobot import is_lerobot_dataset, lerobot_recordings

    return lerobot_recordings(path, args.lerobot_map)[0] if is_lerobot_dataset(path) else path


def run(args) -> int:
    if args.action == "list":
        print(E.format_rows(E.list_episodes(_converted(args.path, args))))
    elif args.action == "show":
        print(E.show(_converted(args.path, args)))
    elif args.action == "trim":
        print(E.trim_episode(args.path, args.episode, args.start, args.end, args.output).summary())
    elif args.action == "delete":
        print(E.delete_episode(args.path, args.episode, args.output).summary())
    elif args.action == "merge":
        print(E.merge(args.path, args.output).summary())
    elif args.action == "phases":
        _phases(args)
    elif args.action == "import":
        _import(args)
    return 0


def _import(args) -> None:
    from hardware.errors import UserError
    from hardware.importers.gello import import_gello

    if args.rate is not None and not args.rate > 0:
        raise UserError(f"--rate must be positive, got {args.rate}")
    out, notes = import_gello(args.path, args.out, args.rate, args.task, say=print)
    for n in notes:
        print(f"note: {n}")
    print(E.format_rows(E.list_episodes(out)))


def _phases(args) -> None:
    from policies.data.recordings import load_episodes
    from policies.labels import labelling as L
    from policies.labels.phases import CONTACT, onsets

    given = thresholds_arg(args)
    episodes, arms = load_episodes(args.path, lerobot_map=args.lerobot_map)
    model = L.load_next(args.next) if args.next is not None else None
    th = L.resolve_thresholds(given, model, episodes, arms)
    labels = [L.label_episode(ep, arms, th, model) for ep in episodes]  # all checked before any PNG
    first = args.path[0]
    out = args.out or ((first if first.is_dir() else first.parent) / "phases")
    tare = "off (--no-tare)" if th.tare == "off" else f"{th.tare} (held loads removed from grasp to release)"
    print(f"thresholds: T_low {th.t_low:.4g}, T_high {th.t_high:.4g} [N*m] ({th.source}); pre-contact 1 s; "
          f"tare {tare}")
    print(f"{'episode':<40} {'seconds':>8} {'free':>6} {'pre':>6} {'contact':>8} {'onsets':>6}  "
          "source; figure")
    n_total, weighted = 0, 0.0
    for ep, lab in zip(episodes, labels):
        sh = lab.shares()
        n_on = len(onsets(lab.phases == CONTACT))
        name, _, index = lab.episode.partition("#")  # "a.mcap#3" -> a_ep3.png
        png = L.plot_labels(lab, th, out / f"{Path(name).stem}{'_ep' + index if index else ''}.png")
        print(f"{lab.episode:<40} {ep.duration_s:8.1f} {sh[0]:6.1%} {sh[1]:6.1%} {sh[2]:8.1%} {n_on:6d}  "
              f"{lab.source}; {png}")
        n_total += len(lab.phases)
        weighted = weighted + len(lab.phases) * sh
    if n_total:
        sh = weighted / n_total
        print(f"{'all':<40} {'':>8} {sh[0]:6.1%} {sh[1]:6.1%} {sh[2]:8.1%}")
