"""`factr2 train-advice RUN...`: the advice lines `factr2 train` prints at its end (what more demonstrations
or more training would buy, read from the run's own validation curve: policies/training/advice.py), for runs
already trained, without training again."""

from __future__ import annotations

from pathlib import Path

HELP = "say what more demonstrations or more training would buy a trained run (its validation curve)"


def add_arguments(p) -> None:
    p.add_argument("runs", nargs="+", metavar="RUN", help="a `factr2 train --out` folder")


def run(args) -> int:
    from hardware.errors import UserError
    from policies.training.advice import run_advice

    for run in map(Path, args.runs):
        try:
            lines = run_advice(run) if run.is_dir() else None
        except ValueError as e:  # a damaged metrics.jsonl or checkpoint JSON
            raise UserError(f"unreadable run: {e}", where=str(run),
                            fix="point at a complete `factr2 train --out` folder") from None
        if not lines:
            raise UserError("not a training run (no checkpoints/last)", where=str(run),
                            fix="point at a `factr2 train --out` folder")
        if len(args.runs) > 1:
            print(f"{run}:")
        for line in lines:
            print(line)
    return 0
