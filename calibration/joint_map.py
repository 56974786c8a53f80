"""Which column of a log is which joint of an arm description: the logs' joint names against the arm's.

    order, note = match_joints(log_names, arm_names, "--joint-map" text or None, arm="ur5")
    columns of the log, reordered: x[:, order] (order[k] = the log column of the arm's joint k)

Rules (one place for `factr2 diagnose` and `factr2 calibrate --from-logs`):
- the same names in the same order: nothing to say;
- the log names no joints: mapped by order (same count), with one line saying so;
- the names differ only by a prefix or suffix common to all of one side's names (`shoulder_pan_joint` vs
  `shoulder_pan`, `j1` vs `joint1`) and, stripped, read in the same order: mapped by order, one line;
- `--joint-map LOG=ARM,...` (every log joint once): reordered to the arm's order -- anything else;
- a real mismatch (another joint count, names that match only in another order, names that do not match)
  is a JointMismatch whose `fix` is a flag that works: the `--joint-map` the names imply (stripped names
  matched in another order: the permutation; unrelated names of the same count: by order), or, for another
  count, the arm the logs come from / `--arm none`.
"""

from __future__ import annotations

import os


class JointMismatch(ValueError):
    """what: one line; fix: the flag that fixes it (a --joint-map that works, or another --arm)."""

    def __init__(self, what: str, fix: str):
        super().__init__(what)
        self.what, self.fix = what, fix


def parse_joint_map(text: str) -> dict[str, str]:
    """'a=x,b=y' -> {'a': 'x', 'b': 'y'} (log name -> arm name); ValueError on anything else."""
    out: dict[str, str] = {}
    for item in text.split(","):
        log, sep, arm = (s.strip() for s in item.partition("="))
        if not sep or not log or not arm or log in out:
            raise ValueError(f"cannot read {item.strip()!r} in --joint-map {text!r}")
        out[log] = arm
    if len(set(out.values())) != len(out):
        raise ValueError(f"--joint-map {text!r} names an arm joint twice")
    return out


def _affixes(names: list[str]) -> tuple[str, str]:
    """The longest prefix and suffix all names share (not the whole of any name)."""
    if len(names) < 2:
        return "", ""
    pre = os.path.commonprefix(names)
    pre = pre[:max(0, min(len(n) for n in names) - 1)]  # every name keeps a character
    rest = [n[len(pre):] for n in names]
    suf = os.path.commonprefix([n[::-1] for n in rest])[::-1]
    return pre, suf[len(suf) - min(len(suf), min(len(n) for n in rest) - 1):] if suf else ""


def _stripped(names: list[str]) -> list[list[str]]:
    """Variants of the names with their common prefix and/or suffix removed (the names themselves first)."""
    pre, suf = _affixes(names)
    out = [list(names)]
    for p, s in ((pre, ""), ("", suf), (pre, suf)):
        if p or s:
            out.append([n[len(p):len(n) - len(s)] for n in names])
    return out


def match_joints(log_names, arm_names, joint_map: str | None = None, arm: str = "description",
                 n_columns: int | None = None) -> tuple[list[int], str]:
    """(order, note): order[k] is the log column of arm joint k; note is "" or the one line to print.
    n_columns: the logs' joint count (needed when they name no joints). JointMismatch when they cannot be
    matched (its `fix` is a flag that works)."""
    log, want = [str(x) for x in log_names], [str(x) for x in arm_names]
    n_log = len(log) if log else (len(want) if n_columns is None else int(n_columns))
    ident = list(range(len(want)))
    if joint_map:
        mapping = parse_joint_map(joint_map)
        names = log or [f"#{k}" for k in range(n_log)]
        unknown = sorted(set(mapping) - set(names))
        renamed = [mapping.get(n, n) for n in names]
        if unknown or sorted(renamed) != sorted(want) or len(renamed) != len(want):
            raise JointMismatch(f"--joint-map gives joints {', '.join(renamed)}, arm {arm} has "
                                f"{', '.join(want)}" + (f" (the logs have no {', '.join(unknown)})"
                                                        if unknown else ""),
                                fix=f"map every log joint ({', '.join(names)}) to one of {', '.join(want)}")
        order = [renamed.index(w) for w in want]
        return order, (f"joints mapped by --joint-map onto arm {arm}'s order" if order != ident else "")
    if log == want:
        return ident, ""
    if n_log != len(want):
        raise JointMismatch(f"the logs' {n_log} joints ({', '.join(log) or 'unnamed'}) are not arm {arm}'s "
                            f"{len(want)} ({', '.join(want)})",
                            fix="pass the --arm the logs were recorded on, or --arm none (no description)")
    if not log:
        return ident, (f"the logs name no joints: their {len(want)} columns are taken in arm {arm}'s order "
                       f"({', '.join(want)})")
    for a in _stripped(log):
        for b in _stripped(want):
            if len(set(a)) != len(a) or sorted(a) != sorted(b):
                continue
            if a == b:
                return ident, (f"the logs' joints ({', '.join(log)}) differ from arm {arm}'s "
                               f"({', '.join(want)}) only by a common prefix/suffix: mapped by order")
            implied = ",".join(f"{log[a.index(x)]}={w}" for x, w in zip(b, want))
            raise JointMismatch(f"the logs' joints ({', '.join(log)}) match arm {arm}'s ({', '.join(want)}) "
                                "only in another order", fix=f"--joint-map {implied}")
    by_order = ",".join(f"{x}={w}" for x, w in zip(log, want))
    raise JointMismatch(f"the logs' joints ({', '.join(log)}) are not arm {arm}'s ({', '.join(want)})",
                        fix=f"--joint-map {by_order} if the columns are in that order, or pass the --arm "
                            "the logs were recorded on")


def reorder(seg, order: list[int], names) -> object:
    """A Segment (hardware.timeseries) with its per-joint columns in `order` and the arm's joint names."""
    import dataclasses

    import numpy as np

    n = seg.q.shape[1]
    cols = {f.name: v[:, order] for f in dataclasses.fields(seg)
            if isinstance(v := getattr(seg, f.name), np.ndarray) and v.ndim == 2 and v.shape[1] == n}
    return dataclasses.replace(seg, **cols, joint_names=tuple(names))
