"""`factr2 train-advice RUN...`: the advice lines `factr2 train` prints at its end (what more demonstrations
or more training would buy, read from the run's own validation curve: policies/training/advice.py), for runs
already trained, without training again."""

from __future__ import annotations

from pathlib import Path

HELP = "say what more demonstrations or more training would buy a trained run (its validation curve)"


def add_arguments(p) -> None:
    p.add_argument("runs", nargs="+", metavar="RUN", help="a `factr2 train --out` folder")


def advice_of(run: Path) -> list[str]:
    """run_advice for one folder; UserError (one line) for a folder that holds no readable run."""
    from hardware.errors import UserError
    from policies.training.advice import run_advice

    try:
        lines = run_advice(run) if run.is_dir() else None
    except ValueError as e:  # a damaged metrics.jsonl or checkpoint JSON
        raise UserError(f"unreadable run: {e}", where=str(run),
                        fix="point at a complete `factr2 train --out` folder") from None
    if not lines:
        raise UserError("not a training run (no checkpoints/last)", where=str(run),
                        fix="point at a `factr2 train --out` folder")
    return lines


def run(args) -> int:
    import sys

    from hardware.errors import UserError

    runs = [Path(r) for r in args.runs]
    if len(runs) == 1:
        print("\n".join(advice_of(runs[0])))  # a bad one: the CLI's one line, exit 2
        return 0
    bad = 0
    for run in runs:  # several (a glob): each said, a bad one in one line without stopping the rest
        try:
            lines = advice_of(run)
        except UserError as e:
            print(f"factr2 train-advice: error: {e}", file=sys.stderr)
            bad += 1
            continue
        print(f"{run}:", *lines, sep="\n")
    return 2 if bad else 0
