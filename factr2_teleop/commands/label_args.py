"""The phase-labelling options shared by `factr2 train`, `factr2 export lerobot` and `factr2 episodes phases`
(policies.labelling does the work): --next CKPT and --thresholds recording|next|LOW:HIGH."""

from __future__ import annotations

from pathlib import Path

from hardware.errors import UserError


def add_label_arguments(p) -> None:
    p.add_argument("--next", type=Path, default=None, metavar="CKPT",
                   help="NEXT checkpoint: estimate tau_ext offline from the logged joint states")
    p.add_argument("--thresholds", default=None, metavar="recording|next|LOW:HIGH",
                   help="contact hysteresis on ||tau_ext||_1 [N*m]: LOW:HIGH, or derived: `recording` "
                        "(default: Otsu's split of the recordings' own scores) or `next` (the NEXT "
                        "checkpoint's free-motion noise: --next, else the one the recordings name)")


def thresholds_arg(args):
    """The parsed --thresholds as policies.labelling.resolve_thresholds takes it: (LOW, HIGH), "next", or
    "recording" (also when absent: the commands' default); UserError with the fix for a bad value."""
    from policies.labelling import THRESHOLD_SOURCES
    from policies.phases import parse_thresholds

    if args.thresholds is None:
        return "recording"
    if args.thresholds in THRESHOLD_SOURCES:
        return args.thresholds
    try:
        return parse_thresholds(args.thresholds)
    except ValueError as e:
        raise UserError(str(e), where="--thresholds",
                        fix="give LOW:HIGH in N*m (e.g. 1.5:2.5), `recording` or `next`") from None
