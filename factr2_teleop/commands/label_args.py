"""The phase-labelling options shared by `factr2 train`, `factr2 export lerobot` and `factr2 episodes phases`
(policies.labelling does the work): --next CKPT and --thresholds LOW:HIGH."""

from __future__ import annotations

from pathlib import Path

from hardware.errors import UserError


def add_label_arguments(p) -> None:
    p.add_argument("--next", type=Path, default=None, metavar="CKPT",
                   help="NEXT checkpoint: estimate tau_ext offline from the logged joint states (and take "
                        "the default thresholds from its free-motion noise)")
    p.add_argument("--thresholds", default=None, metavar="LOW:HIGH",
                   help="contact hysteresis on ||tau_ext||_1 [N*m] (default: from the NEXT checkpoint's "
                        "noise)")


def thresholds_arg(args):
    """The parsed --thresholds (policies.phases), or None; UserError with the fix for a bad value."""
    from policies.phases import parse_thresholds

    if args.thresholds is None:
        return None
    try:
        return parse_thresholds(args.thresholds)
    except ValueError as e:
        raise UserError(f"--thresholds {e}", where="--thresholds",
                        fix="give LOW:HIGH in N*m, e.g. --thresholds 1.5:2.5") from None
