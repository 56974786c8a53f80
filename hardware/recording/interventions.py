"""An operator's interventions in a rollout recording (issue #33), read back: who drove each tick, the
takeover and hand-back marks, and each tick's training source (demonstration, policy, pre-intervention,
operator).

Written by factr2_teleop/session/takeover_switch.py: /rollout/driver on a change (so the driver at any time
is the latest value at or before it: previous-value hold, exact per tick) and "takeover" / "handback" events
(text: JSON with "by" and "pre_window_s"). docs/recording.md names them.
"""

from __future__ import annotations

import json
import math

import numpy as np

from hardware.recording import schemas as S
from hardware.timeseries import hold_previous

SOURCE_DEMO, SOURCE_POLICY, SOURCE_PRE, SOURCE_OPERATOR = range(4)
SOURCE_NAMES = ("demo", "policy", "pre", "operator")  # by code: a training sample's source


def is_rollout(ep) -> bool:
    """A policy rollout's episode (its recording metadata says operator "policy", or it has driver marks)."""
    return ep.recording.info.get("operator") == "policy" or S.TOPIC_ROLLOUT_DRIVER in ep.topics


def driver_on_grid(ep, grid: np.ndarray) -> np.ndarray:
    """Who drove at each time of grid [s]: S.DRIVER_POLICY / S.DRIVER_OPERATOR (int8); policy where the
    episode has no driver marks (a rollout without takeover)."""
    if S.TOPIC_ROLLOUT_DRIVER not in ep.topics:
        return np.zeros(len(grid), np.int8)
    ta = ep.recording.topic(S.TOPIC_ROLLOUT_DRIVER)  # the whole file: the mark before the episode counts
    if not len(ta.t):
        return np.zeros(len(grid), np.int8)
    return np.asarray(hold_previous(ta.t, np.asarray(ta.fields["driver"]), np.asarray(grid, float)), np.int8)


def interventions(ep) -> list[dict]:
    """The episode's interventions in order: {"t_takeover", "t_handback" (the episode's end when the operator
    still drove then), "by" (who took over: hand / key), "handback_by", "pre_window_s"} [s]."""
    out: list[dict] = []
    for e in ep.events:
        if e["kind"] not in S.TAKEOVER_KINDS:
            continue
        try:
            info = json.loads(e["text"] or "{}")
        except ValueError:
            info = {}
        if e["kind"] == "takeover":
            out.append({"t_takeover": float(e["t"]), "t_handback": math.nan, "by": info.get("by", "?"),
                        "handback_by": "", "pre_window_s": float(info.get("pre_window_s", 0.0))})
        elif out and not math.isfinite(out[-1]["t_handback"]):
            out[-1]["t_handback"] = float(e["t"])
            out[-1]["handback_by"] = info.get("by", "?")
    for m in out:
        if not math.isfinite(m["t_handback"]) or m["t_handback"] > ep.t_stop:
            m["t_handback"] = float(ep.t_stop)
    return out


def source_on_grid(ep, grid: np.ndarray) -> np.ndarray:
    """Each grid time's training source (int8 codes of SOURCE_NAMES): SOURCE_DEMO in a demonstration; in a
    rollout SOURCE_OPERATOR where the operator drove, SOURCE_PRE where the policy drove within an
    intervention's pre-window before its takeover, SOURCE_POLICY elsewhere."""
    grid = np.asarray(grid, float)
    if not is_rollout(ep):
        return np.full(len(grid), SOURCE_DEMO, np.int8)
    src = np.where(driver_on_grid(ep, grid) == S.DRIVER_OPERATOR, SOURCE_OPERATOR, SOURCE_POLICY)
    for m in interventions(ep):
        pre = (grid >= m["t_takeover"] - m["pre_window_s"]) & (grid < m["t_takeover"])
        src[pre & (src == SOURCE_POLICY)] = SOURCE_PRE
    return src.astype(np.int8)


def describe(ep) -> list[str]:
    """One line per intervention (`factr2 episodes show`)."""
    return [f"intervention {k + 1}: {m['t_takeover'] - ep.t_start:.2f} s .. "
            f"{m['t_handback'] - ep.t_start:.2f} s after the start "
            f"({m['t_handback'] - m['t_takeover']:.2f} s, taken by {m['by']}, handed back by "
            f"{m['handback_by'] or 'the episode end'}; pre-window {m['pre_window_s']:g} s)"
            for k, m in enumerate(interventions(ep))]
