"""The one per-tick record of an arm pair: what the loop hands to the recorder hook, the UI snapshot and the
demo's metrics. Typed fields, not string keys; a recording names the same values with hardware.features.

The leader law's torque terms are named by leader_law.TERMS ("gravity", "friction", "barrier", "null_space",
"damping", "feedback"); tau_term(name) reads one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from hardware.types import JointState


@dataclass
class TickRecord:
    """t: loop time of the tick [s]; pair: pair name ("arm", or "left"/"right"); phase: the pair's
    phase (pair.SOFT_START, COUPLED, HOLD, ...); leader / follower: the samples the tick used;
    leader_tau_cmd: torque sent to the leader after its safety layer [N*m]; leader_tau_terms: the law's terms
    [N*m]; tau_ext: the estimate fed back [N*m] (NaN: none); action_q / action_gripper: the follower target
    after its safety layer [rad] / [m] (NaN: nothing sent this tick); action_hold: the layer turned it into a
    hold; gate, contact, fresh: the feedback gate [0, 1], the contact hysteresis and the estimate's freshness;
    leader_gripper_tau_fb: gripper feedback [N*m]; loop_period_s: time since the previous tick [s];
    loop_overruns: ticks late so far; loop_busy_s: wall time the loop spent inside the previous tick [s];
    loop_late_s: how long after its deadline this tick started [s] (NaN: not measured)."""

    t: float
    pair: str
    phase: str
    leader: JointState
    follower: JointState
    leader_tau_cmd: np.ndarray
    tau_ext: np.ndarray
    action_q: np.ndarray
    action_gripper: float = float("nan")
    action_hold: bool = False
    leader_tau_terms: Mapping[str, np.ndarray] = field(default_factory=dict)  # read-only
    gate: float = 0.0
    contact: bool = False
    fresh: bool = False
    leader_gripper_tau_fb: float = 0.0
    loop_period_s: float = float("nan")
    loop_overruns: int = 0
    loop_busy_s: float = float("nan")
    loop_late_s: float = float("nan")
    perturb_q: np.ndarray | None = None  # the perturbation offset added to the target this tick [rad]
    # (teleop/perturb.py; zeros outside its windows; None: no perturbation in this collection)

    def tau_term(self, name: str) -> np.ndarray | None:
        """One leader-law term [N*m] (None when the law did not run this tick)."""
        return self.leader_tau_terms.get(name)

    @property
    def tau_feedback(self) -> np.ndarray | None:
        """The force-feedback term sent to the leader [N*m] (None when the law did not run)."""
        return self.leader_tau_terms.get("feedback")
