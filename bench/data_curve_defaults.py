"""The data curve's named sets of training defaults (bench/data_curve.py --defaults NAME, issue #56 item 2):
`current` (factr2 train with no option: the defaults of the commit), one lever each, and `sized`, the
candidate rule from the number of successful demonstrations. In one place: the curve, the development runs
and the record of what an OUT was trained with all read it here. Not validated yet: docs/data_curve.md,
"Choosing the defaults", says how it is to be fitted on development seeds and checked on the curve's.
"""

from __future__ import annotations

import argparse
import json

# the candidate rule's levers (issue #56 item 2; not validated yet:
# docs/data_curve.md "Choosing the defaults")
OBS_NOISE = "state=0.05,objects=0.05,force=0.1"  # [normalised units: each input's std over the training data]
SIZED_BELOW = 100  # successful demonstrations from which `sized` adds nothing to the current defaults


def sized(n: int) -> list[str]:
    """The candidate rule from n successful demonstrations: below SIZED_BELOW, where the validation loss
    turns up (the data limits the policy), noise on the low-dimensional inputs and dropout 0.1 with today's
    length (success still rose with steps past the validation minimum on peg-insert); from SIZED_BELOW on,
    today's defaults."""
    return ["--obs-noise", OBS_NOISE, "--dropout", "0.1"] if n < SIZED_BELOW else []


# named sets of `factr2 train` flags beyond DEMOS --obs state, each a list or a rule from the number of
# successful demonstrations: "current" = none, the defaults of the commit; one lever each; the candidate rule
DEFAULTS = {"current": [], "noise": ["--obs-noise", OBS_NOISE], "dropout": ["--dropout", "0.1"],
            "val-min": ["--keep", "val-min"], "longer": ["--epochs", "160"], "sized": sized}
RULE_PROBE = (12, 25, 50, 100, 200, 400)  # where a rule's flags are resolved for OUT's record of them
# training options added after the curve started, left out of OUT's record of the defaults while off (at the
# value every run before them had), so an OUT started before them still resumes
LATER_OFF = ("obs_noise", "keep")


def defaults_flags(defaults: str, n: int) -> list[str]:
    """The named defaults' `factr2 train` flags for a point of n successful demonstrations."""
    d = DEFAULTS[defaults]
    return list(d(n) if callable(d) else d)


def defaults_meta(defaults: str) -> dict:
    """What `factr2 train DEMOS --obs state` with the named defaults' flags resolves to before it reads data
    (the checkpoint meta's model, method and schedule; not the seed or threads), for a rule at each of
    RULE_PROBE's sizes: kept in OUT/config.json, so an OUT is never resumed under other defaults, a later
    commit's."""
    from policies.training.run import ADDED_TRAIN
    from policies.training.run_config import add_arguments, from_args

    def meta_of(flags: list[str]) -> dict:
        ap = argparse.ArgumentParser()
        add_arguments(ap)
        meta = from_args(ap.parse_args(["DEMOS", "--obs", "state", *flags, "--out", "RUN"])).to_meta()
        meta["train"] = {k: v for k, v in meta["train"].items() if k not in ("seed", "threads")
                         and not (k in LATER_OFF and v == ADDED_TRAIN[f"train.{k}"])}
        return json.loads(json.dumps(meta))

    if not callable(DEFAULTS[defaults]):
        return meta_of(DEFAULTS[defaults])
    return {f"n{n}": meta_of(defaults_flags(defaults, n)) for n in RULE_PROBE}
