"""Who drives a rollout's followers, the policy or the operator (issue #33): Takeover, the rollout-wide switch
between them with the marks of each intervention and their recording, and the rollout's takeover summary.
The pairs that sense the hand and follow the switch: session/rollout_takeover.py (TakeoverPair).
"""

from __future__ import annotations

import json
import logging
import math
import queue

import numpy as np

from factr2_teleop.session.read_back import autonomous_successes
from factr2_teleop.session.rollout_pair import RUN, PolicyTarget
from factr2_teleop.teleop.takeover import (
    HANDBACK,
    OPERATOR,
    POLICY,
    TAKEOVER,
    DetectorState,
    TakeoverConfig,
    detect_step,
    switched,
)
from hardware.reasons import Reason
from hardware.recording.schemas import DRIVER_OPERATOR, DRIVER_POLICY

TOGGLE_KEY = "o"  # the key (or pedal) that takes over / hands back, in the CLI and the terminal app


class Takeover:
    """Who drives every follower of a rollout, and the marks of each intervention. The loop's thread calls
    sense() from each pair's tick; keys come through `keys` (a queue: TOGGLE_KEY) from any thread.
    target: the rollout's PolicyTarget; recording: the session's SessionRecording or None."""

    def __init__(self, cfg: TakeoverConfig, target: PolicyTarget, n_pairs: int, recording=None):
        self.cfg, self.target, self.recording = cfg, target, recording
        self.keys: queue.SimpleQueue = queue.SimpleQueue()
        self.state = DetectorState()
        self.driver = POLICY  # the follower's source this tick
        self.pending = False  # handed back; the leaders drive until the policy's fresh chunk is there
        self.held = False  # a fault during a handover held both arms
        # held (a pedal held down; the twin operator while its script runs): no hand-back at rest, key only
        self.clutch = False
        self.count = 0
        self.marks: list[dict] = []  # per intervention: t_grab, t_takeover, t_tracking, t_handback, by
        self.hand_nm = [0.0] * n_pairs  # each pair's hand torque at its last tick [N*m]
        self._q: list = [np.zeros(0)] * n_pairs  # each pair's leader joints at its last tick [rad]
        self._t_grab = math.nan  # s: the hand torque reached grab_nm (the latency's start)
        self.t_switch = -math.inf  # s: the follower's source last changed
        self.epoch = 0  # +1 when an episode's policy starts and at every change of driver (hand baselines)
        self._armed = False

    # -- what the UI shows --------------------------------------------------------------------------------
    @property
    def hand_max_nm(self) -> float:
        return max(self.hand_nm)

    def press(self) -> None:
        """The key (or pedal): take over, or hand back (thread-safe)."""
        self.keys.put(TOGGLE_KEY)

    # -- per tick (the loop's thread) ---------------------------------------------------------------------
    def sense(self, i: int, now: float, hand_nm: float, q_leader: np.ndarray) -> None:
        """Pair i's hand torque [N*m] and leader joints [rad] this tick; pair 0 decides for all (from the
        others' values of their last tick)."""
        self.hand_nm[i], self._q[i] = hand_nm, q_leader
        if i == 0:
            self._decide(now)

    def _decide(self, now: float) -> None:
        armed = self.target.state == RUN
        if armed and not self._armed:  # an episode's policy starts: its first driver mark
            self._log_driver(now, DRIVER_POLICY)
            self.epoch += 1
        if not armed:
            if self.driver == OPERATOR:
                self._end(now, "episode end")
            self.held = False
            self._drain()
            self._armed = False
            return
        self._armed = True
        if self.held:
            self._drain()
            return
        hand = self.hand_max_nm
        if self.driver == POLICY and hand >= self.cfg.grab_nm and not math.isfinite(self._t_grab):
            self._t_grab = now
        elif hand < self.cfg.release_nm and self.driver == POLICY:
            self._t_grab = math.nan
        if self._drain():
            event = TAKEOVER if self.state.driver == POLICY else HANDBACK
            by = "key"
        elif self.driver == OPERATOR and self.clutch:
            self.state, event, by = switched(OPERATOR), None, ""
        else:
            q = self._q[0] if len(self._q) == 1 else np.concatenate(self._q)
            self.state, event = detect_step(self.state, now, hand, q, self.cfg)
            by = "hand"
        if event == TAKEOVER:
            self._take(now, by)
        elif event == HANDBACK:
            self._hand_back(now, by)

    def _drain(self) -> bool:
        """Whether the key was pressed (an odd number of presses since the last tick)."""
        n = 0
        while not self.keys.empty():
            self.keys.get_nowait()
            n += 1
        return n % 2 == 1

    def _take(self, now: float, by: str) -> None:
        self.state = switched(OPERATOR)
        self.count += 1
        t_grab = self._t_grab if math.isfinite(self._t_grab) and by == "hand" else now
        self.marks.append({"t_grab": t_grab, "t_takeover": now, "t_tracking": math.nan,
                           "t_handback": math.nan, "by": by})
        self._t_grab = math.nan
        self.pending = False
        self._event(now, TAKEOVER, by)
        if self.driver != OPERATOR:
            self._set_driver(now, OPERATOR)

    def _hand_back(self, now: float, by: str) -> None:
        self.state = switched(POLICY)
        self.marks[-1]["t_handback"] = now
        self._event(now, HANDBACK, by)
        self.target.replan(now)
        self.pending = True

    def _end(self, now: float, by: str) -> None:
        """The episode ended (or a fault) while the operator drove: the intervention ends there."""
        if self.marks and not math.isfinite(self.marks[-1]["t_handback"]):
            self.marks[-1]["t_handback"] = now
            self._event(now, HANDBACK, by)
        self.state, self.pending = switched(POLICY), False
        self._set_driver(now, POLICY)

    def policy_resumes(self, now: float) -> None:
        """The policy's fresh chunk is there after a hand-back: it drives from this tick."""
        self.pending = False
        self._set_driver(now, POLICY)

    def tracking(self, now: float) -> None:
        """The follower's target reached the leader's pose after the last takeover (latency's end)."""
        if self.marks and not math.isfinite(self.marks[-1]["t_tracking"]):
            self.marks[-1]["t_tracking"] = now

    def fault(self, now: float, why: Reason) -> None:
        """A fault during a handover: both arms of every pair held until the episode ends."""
        if self.held:
            return
        self.held = True
        logging.getLogger("factr2.teleop").warning("takeover: %s during a handover: every arm held", why)
        if self.driver == OPERATOR or self.pending:
            self._end(now, "fault")

    def in_handover(self, now: float) -> bool:
        """Within a switch's blend, or waiting for the policy after a hand-back."""
        return self.pending or now - self.t_switch < self.cfg.blend_s

    # -- the recording --------------------------------------------------------------------------------
    def _set_driver(self, now: float, driver: str) -> None:
        if driver != self.driver:
            self.driver = driver
            self.t_switch = now
            self.epoch += 1
            self._log_driver(now, DRIVER_OPERATOR if driver == OPERATOR else DRIVER_POLICY)

    def _log_driver(self, now: float, code: int) -> None:
        rec = self.recording
        if rec is not None and rec.recording:
            rec.recorder.log_driver(now, code, self.hand_max_nm)

    def _event(self, now: float, kind: str, by: str) -> None:
        rec = self.recording
        if rec is not None and rec.recording:
            rec.recorder.log_event(now, kind, json.dumps({"by": by, "pre_window_s": self.cfg.pre_window_s}),
                                   self.hand_max_nm)

    def summary(self) -> dict:
        """Interventions: count, who, and per takeover the latency from the hand torque over its threshold
        to the switch and to the follower tracking the leader [ms]."""
        lat = [1e3 * (m["t_tracking"] - m["t_grab"]) for m in self.marks if math.isfinite(m["t_tracking"])]
        det = [1e3 * (m["t_takeover"] - m["t_grab"]) for m in self.marks]
        return {"takeovers": self.count, "by": [m["by"] for m in self.marks],
                "operator_s": float(sum(m["t_handback"] - m["t_takeover"] for m in self.marks
                                        if math.isfinite(m["t_handback"]))),
                "detect_latency_ms": det, "tracking_latency_ms": lat}


def takeover_summary(tk: Takeover, pairs, episodes) -> dict:
    """The rollout's interventions (Takeover.summary), per episode (takeovers, success without one), and
    the leaders' tracking error while the policy drove [rad, leader joints: max over joints per tick]."""
    for m in tk.marks:  # the loop stopped with the last episode while the operator drove: it ended there
        if not math.isfinite(m["t_handback"]):
            m["t_handback"] = next((e.t_end for e in episodes if e.t_start <= m["t_takeover"] <= e.t_end),
                                   m["t_takeover"])
    out = tk.summary()
    per = [sum(1 for m in tk.marks if e.t_start <= m["t_takeover"] <= e.t_end) for e in episodes]
    out["per_episode"] = per
    out["autonomous_successes"] = autonomous_successes([e.outcome for e in episodes], per)
    err = np.concatenate([np.asarray(p.tracking_err_rad, float) for p in pairs
                          if getattr(p, "tracking_err_rad", None)] or [np.zeros(0)])
    if err.size:
        out["leader_tracking_err_rad"] = {"p50": float(np.percentile(err, 50)),
                                          "p99": float(np.percentile(err, 99)), "max": float(err.max()),
                                          "ticks": int(err.size)}
    return out
