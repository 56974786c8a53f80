"""The `factr2` command line. Each subcommand is a module in factr2_teleop/commands/ exposing

    HELP: str                                   one line for `factr2 --help`
    def add_arguments(parser) -> None            its options
    def run(args) -> int                         exit code

so subcommands are added without touching this file. Errors the user can fix (hardware.errors.UserError,
a missing file, a bad value) print one line and exit 2; Ctrl-C exits 130; no tracebacks unless --debug.
SIGTERM takes Ctrl-C's path (arms safe, recording closed) and exits 143.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import signal
import sys
import threading

from factr2_teleop import __version__
from factr2_teleop import commands as _commands_pkg
from hardware.errors import UserError


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread: every command's Ctrl-C path leaves the arms safe and closes the
    recording (a service manager's stop, `kill PID`)."""


def _on_sigterm(signum, frame) -> None:
    raise Terminated("SIGTERM")


def _command_modules():
    for info in sorted(pkgutil.iter_modules(_commands_pkg.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{_commands_pkg.__name__}.{info.name}")
        if hasattr(mod, "run") and hasattr(mod, "add_arguments"):
            yield info.name.replace("_", "-"), mod


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="factr2", description="FACTR 2 force-feedback teleoperation, "
                                "NEXT calibration and FIRST training on commodity arms (or their twins).")
    p.add_argument("--version", action="version", version=f"factr2 {__version__}")
    p.add_argument("--debug", action="store_true", help="show full tracebacks")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name, mod in _command_modules():
        sp = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(sp)
        sp.set_defaults(_run=mod.run)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 0
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return int(args._run(args) or 0)
    except Terminated:
        print(f"factr2 {args.command}: terminated (SIGTERM): stopped safely", file=sys.stderr)
        return 143
    except UserError as e:
        if args.debug:
            raise
        print(f"factr2 {args.command}: error: {e}", file=sys.stderr)
        return e.exit_code
    except FileNotFoundError as e:
        if args.debug:
            raise
        print(f"factr2 {args.command}: error: {e.filename or e}: no such file -- check the path",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"factr2 {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
