"""The phase-labelling options shared by `factr2 train` (policies.training.run_config),
`factr2 export lerobot` and `factr2 episodes phases` (policies.labels.labelling does the work): --next CKPT,
--thresholds recording|next|LOW:HIGH, --no-tare and --contact-score l1|motion."""

from __future__ import annotations

from pathlib import Path

from hardware.errors import UserError
from policies.labels.motion_residual import CONTACT_SCORES

NEXT_HELP = "NEXT checkpoint: estimate tau_ext offline from the logged joint states"


def add_label_arguments(p) -> None:
    p.add_argument("--next", type=Path, default=None, metavar="CKPT", help=NEXT_HELP)
    add_threshold_arguments(p)


def add_threshold_arguments(p) -> None:
    """--thresholds, --no-tare and --contact-score (read back by thresholds_arg)."""
    p.add_argument("--thresholds", default=None, metavar="recording|next|LOW:HIGH",
                   help="contact hysteresis on ||tau_ext||_1 [N*m]: LOW:HIGH, or derived: `recording` "
                        "(default: Otsu's split of the recordings' own scores) or `next` (the NEXT "
                        "checkpoint's free-motion noise: --next, else the one the recordings name)")
    p.add_argument("--no-tare", action="store_true",
                   help="score the raw tau_ext: no tare of a held object's load (by default the load, "
                        "estimated on the free motion right after each grasp, is removed until the release)")
    p.add_argument("--contact-score", choices=CONTACT_SCORES, default="l1",
                   help="what the contact labels split: `l1` ||tau_ext||_1 (the paper's, default) or "
                        "`motion`: "
                        "the part of tau_ext the joint velocities do not explain, fitted on the recordings "
                        "themselves (for an estimator whose free-motion error follows the motion; "
                        "docs/first_labels.md); needs --thresholds recording")


def thresholds_arg(args):
    """The parsed --thresholds and --no-tare as policies.labels.labelling.resolve_thresholds takes them: a
    LabelChoice of (LOW, HIGH), "next", or "recording" (also when absent: the commands' default) and the tare
    method ("off" with --no-tare); UserError with the fix for a bad value."""
    from policies.labels.labelling import TARE_DEFAULT, THRESHOLD_SOURCES, LabelChoice
    from policies.labels.phases import parse_thresholds

    tare = "off" if getattr(args, "no_tare", False) else TARE_DEFAULT
    score = getattr(args, "contact_score", None) or "l1"
    if args.thresholds is None:
        return LabelChoice("recording", tare, score)
    if args.thresholds in THRESHOLD_SOURCES:
        return LabelChoice(args.thresholds, tare, score)
    try:
        return LabelChoice(parse_thresholds(args.thresholds), tare, score)
    except ValueError as e:
        raise UserError(str(e), where="--thresholds",
                        fix="give LOW:HIGH in N*m (e.g. 1.5:2.5), `recording` or `next`") from None
