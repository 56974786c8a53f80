"""Operator takeover during a policy rollout (issue #33): the shell around teleop/takeover.py's pure math.

TakeoverPair is a RolloutPair whose leader is no longer passive: every tick it gets teleop's own leader law
(gravity, friction, barrier, the force feedback with teleop's gating and caps: LeaderLaw.step) plus, while the
policy drives, the weak following spring toward the follower (capped by the rig file's follow_tau_max_nm and
the leader's tau_max, then the leader's safety layer). The follower's target comes from the policy or, after a
takeover, from the leader through the pair's joint map, as in teleop; a switch fades the gap between the two
and is rate-limited (handover_target), so no command steps.

Takeover is rollout-wide (one policy moves every arm): the hand on any leader, or the key, hands every
follower to its leader; hand-back (the key, or every hand at rest for rest_s) asks the policy for a fresh
chunk at once (PolicyTarget.replan: nothing observed before is executed); the leaders keep driving until it
is there. A fault (stale data, a motor error) during a handover holds both arms of every pair (make_safe)
until the episode ends; a fault otherwise holds as a rollout does.

Takeover (who drives, the marks, the summary) is session/takeover_switch.py. Recording: /rollout/driver on a
change (per-tick driver = previous-value hold, exact), "takeover" / "handback" events with who did it and the
pre-intervention window (docs/recording.md).
"""

from __future__ import annotations

import logging
import math
import queue

import numpy as np

from factr2_teleop.session.rollout_pair import PolicyTarget, RolloutPair
from factr2_teleop.session.takeover_switch import Takeover
from factr2_teleop.teleop.pair import COUPLED, HOLD, PairHold
from factr2_teleop.teleop.record import TickRecord
from factr2_teleop.teleop.takeover import (
    BASELINE_ADAPT_NM,
    OPERATOR,
    POLICY,
    blend_gripper,
    blend_weight,
    follow_torque,
    gripper_pickup,
    hand_baseline_step,
    hand_torque_nm,
    handover_target,
    lag_allowance,
    leader_goal,
    spring_torque_nm,
)
from hardware.params import per_joint
from hardware.reasons import Reason
from hardware.types import FollowerCommand
from policies.rollout.schedule import PolicyHold

TRACKING_TOL_RAD = 0.01  # rad: the follower "tracks the leader" once its target is this close to the leader's


class TakeoverPair(RolloutPair):
    """A RolloutPair whose leader follows while the policy drives and drives after a takeover (module doc).
    Without attach() it is a RolloutPair."""

    takeover: Takeover | None = None
    index = 0

    def attach(self, takeover: Takeover, index: int) -> None:
        self.takeover, self.index = takeover, int(index)

    def begin(self, clock=None) -> None:
        super().begin(clock)
        tc, n = self.cfg.takeover, self.leader.n_joints
        where = f"{self.cfg.name}.takeover"
        self._kp = per_joint(tc.follow_kp_nm_rad, n, f"{where}.follow_kp_nm_rad", nonneg=True)
        self._kd = per_joint(tc.follow_kd_nm_s_rad, n, f"{where}.follow_kd_nm_s_rad", nonneg=True)
        self._drag = per_joint(tc.follow_drag_nm_s_rad, n, f"{where}.follow_drag_nm_s_rad", nonneg=True)
        self._lag = per_joint(tc.follow_lag_nm_s_rad, n, f"{where}.follow_lag_nm_s_rad", nonneg=True)
        cap = per_joint(tc.follow_tau_max_nm, n, f"{where}.follow_tau_max_nm", nonneg=True)
        self._cap = np.minimum(cap, self.leader.safety.limits.tau_max)  # the leader's limits bound it
        self.law.reset(self.leader.last_state.q)
        self._src, self._t_sw = POLICY, -math.inf
        self._offset = np.zeros(self.follower.n_joints)
        self._g_off, self._g_cmd = 0.0, None
        self._g_pick = None  # (held gripper command [m], gripper_pickup's pick) until the trigger picks it up
        self._t_gsw = -math.inf  # when the gripper's gap started to fade [s]
        self.hand_nm = 0.0
        self._allow = np.zeros(n)  # [N*m] the spring torque the leader's lag may explain (lag_allowance)
        self._base: np.ndarray | None = None  # [N*m] the leader's slow load on the spring (baseline)
        self._epoch = -1  # the Takeover.epoch the baseline was taken in
        self.tracking_err_rad: list[float] = []  # leader vs follower (leader joints) while the policy drives
        self._safe = False

    def tick(self, now: float) -> TickRecord:
        tk = self.takeover
        if tk is None:
            return super().tick(now)
        self._note_loop_gap(now)
        dt, ls, fs, leader_ok, follower_ok = self._read_both(now)
        errors = self._check_samples(ls, fs)
        leader_ok = leader_ok and "leader" not in errors
        follower_ok = follower_ok and "follower" not in errors and self._fresh_since_gap(fs)
        goal = leader_goal(self.map.backward(fs.q), ls.q)
        qd_goal = self.map.backward_velocity(fs.q_dot)
        ok = leader_ok and follower_ok
        self.hand_nm = self._sense_hand(dt, ls, goal, qd_goal, tk.driver) if ok else 0.0
        tk.sense(self.index, now, self.hand_nm, ls.q)
        if follower_ok:
            self._tick_estimator(now, fs, self.q_target if self.q_target is not None else fs.q)
        self.sent = None
        if not ok or tk.held:
            if not ok and tk.in_handover(now):
                tk.fault(now, Reason.of(PairHold.DATA_STALE, who="leader" if not leader_ok else "follower",
                                        age_ms=float("nan")))
            return self._unsafe(now, ls, fs, leader_ok, tk.held)
        self._safe = False
        out, tau_sent = self._lead(now, ls, fs, goal, qd_goal, tk.driver == POLICY)
        self._follow(now, dt, ls, fs, tk)
        self.last = self._record(now, ls, fs, tau_sent, out)
        return self.last

    def _sense_hand(self, dt: float, ls, goal, qd_goal, driver: str) -> float:
        """The hand torque [N*m] (teleop/takeover.py): while the policy drives, the spring's torque less its
        baseline and the lag allowance, the baseline adapting while no hand is sensed; while the operator
        drives (no spring acts), the leader-follower gap as it is (the hand at rest hands back)."""
        tc = self.cfg.takeover
        spring = spring_torque_nm(ls.q, goal, self._kp)
        dt = dt if np.isfinite(dt) and dt > 0 else self.dt_s
        self._allow = lag_allowance(self._allow, qd_goal, self._lag, dt, tc.follow_lag_hold_s)
        if self._base is None or (driver == POLICY and self._epoch != self.takeover.epoch):
            # the policy starts or resumes driving, no hand on the leader (an episode starts; the hand
            # handed back): the baseline frozen meanwhile belongs to another pose. Measured: every second
            # takeover of the DAgger round came ~1 s after a hand-back, on the stale baseline
            self._base, self._epoch = np.nan_to_num(spring), self.takeover.epoch
        base = self._base if driver == POLICY else 0.0
        hand = hand_torque_nm(spring, base, self._allow, qd_goal, tc.grab_max_speed_rad_s)
        if driver == POLICY and hand < tc.release_nm and float(self._allow.max()) > BASELINE_ADAPT_NM:
            self._base = hand_baseline_step(self._base, spring, dt, tc.hand_baseline_s)
        return hand

    def _lead(self, now: float, ls, fs, goal, qd_goal, following: bool):
        """The leader's torque: teleop's law (feedback gated and capped as in teleop) + the spring."""
        extra = None
        if following:
            tau = follow_torque(ls.q, ls.q_dot, goal, qd_goal, self._kp, self._kd, self._drag, self._cap)
            law = self.law
            if law.cfg.gravity.enabled:  # the rest of g(q) the law leaves to a hand (gain < 1): no sag
                tau = tau + (1.0 - law.g_gain) * law.gravity(np.asarray(ls.q, dtype=float))
            extra = {"follow": np.clip(tau, -self._cap, self._cap)}
            if self.phase == COUPLED:
                self.tracking_err_rad.append(float(np.max(np.abs(goal - ls.q))))
        out = self.law.step(self._leader_inputs(now, ls, fs), feedback_on=self.phase == COUPLED, extra=extra)
        if out.message:
            self._say(out.message)
        return out, self.leader.command_torque(out.tau)

    def _follow(self, now: float, dt: float, ls, fs, tk: Takeover) -> None:
        """The follower's target from this tick's source, across a switch without a step."""
        if tk.driver == OPERATOR:
            q, grip, why = self.map.forward(ls.q), self.map.gripper_forward(ls.gripper_pos), None
            if tk.pending:
                qp, gp, _ = self.target_fn(now, fs)
                if qp is not None:
                    tk.policy_resumes(now)
                    q, grip = qp, gp
        else:
            q, grip, why = self.target_fn(now, fs)
        src = tk.driver
        if q is None:
            self._policy_hold(why)
            return
        prev = self.q_target if self.q_target is not None else np.asarray(fs.q, dtype=float)
        if src != self._src:  # this pair's source changes: the gap fades over blend_s
            self._src, self._t_sw = src, now
            self._offset = prev - np.asarray(q, dtype=float)
            self._g_off = (self._g_cmd - grip) if (self._g_cmd is not None and grip is not None) else 0.0
            self._t_gsw = now
            # to the operator, the gripper keeps the policy's command until the trigger picks it up
            self._g_pick = (self._g_cmd, None) if src == OPERATOR and self._g_cmd is not None else None
        w = blend_weight(now - self._t_sw, self.cfg.takeover.blend_s)
        self.q_target = handover_target(q, self._offset, w, prev, self._rate_now(), dt)
        self._caught_up(q)
        if self._g_pick is not None:
            held, g_lead = self._g_pick[0], grip
            grip, picked, pick = gripper_pickup(held, g_lead, self._g_pick[1])
            self._g_pick = None if picked else (held, pick)
            if picked:  # from here the trigger: what is left of the gap fades over blend_s
                self._g_off, self._t_gsw, grip = held - g_lead, now, held
        else:
            grip = blend_gripper(grip, self._g_off, blend_weight(now - self._t_gsw,
                                                                 self.cfg.takeover.blend_s))
        self._g_cmd = grip if grip is not None else self._g_cmd
        self.sent = self.follower.command(FollowerCommand(q=self.q_target, gripper=grip))
        if src == OPERATOR and bool(np.all(np.abs(self.q_target - q) <= TRACKING_TOL_RAD)):
            tk.tracking(now)
        self._hold_why = None
        if self.phase != COUPLED:
            self.phase = COUPLED
            self._say(f"follower follows the {'leader' if src == OPERATOR else 'policy'}", logging.INFO)

    def _policy_hold(self, why: Reason) -> None:
        """The policy has no target (RolloutPair's hold, said once per kind, faults counted)."""
        if self.phase != HOLD:
            self.follower.hold(why)
            self.phase = HOLD
        kind = why.kind
        if kind != self._hold_why:
            if isinstance(kind, PolicyHold) and kind.fault:
                self.holds[why.key] += 1
            self._say(f"follower on hold: {why}")
        self._hold_why = kind
        self.q_target = None

    def _unsafe(self, now: float, ls, fs, leader_ok: bool, held: bool) -> TickRecord:
        """Stale data or a motor error: the follower holds; the leader gets zero torque (held: after a fault
        in a handover, or its own data stale), else teleop's law without the spring (no feedback)."""
        if held:
            if not self._safe:
                self.make_safe(Reason.of(PairHold.LOOP_FAULT))
                self._safe = True
                self._say("fault during a handover: both arms held until the episode ends")
            self.phase, self.q_target = HOLD, None
            tau = self.leader.command_torque(np.zeros(self.leader.n_joints)) if leader_ok else None
            self.last = self._record(now, ls, fs, tau if tau is not None else np.zeros(self.leader.n_joints),
                                     None)
            return self.last
        self._policy_hold(Reason.of(PolicyHold.FOLLOWER_STALE))
        out = None
        if leader_ok:
            out = self.law.step(self._leader_inputs(now, ls, fs), feedback_on=False)
            tau = self.leader.command_torque(out.tau)
        else:
            if not self._safe:  # once: a leader that stopped answering may refuse writes too
                self._safe = True
                try:
                    self.leader.zero_torque(Reason.of(PairHold.DATA_STALE, who="leader", age_ms=float("nan")))
                except Exception as e:  # noqa: BLE001 -- the follower is held already
                    self._say(f"leader zero torque failed ({type(e).__name__}: {e})")
            tau = np.zeros(self.leader.n_joints)
        self.last = self._record(now, ls, fs, tau, out)
        return self.last


def attach_takeover(ts, target: PolicyTarget, keys: queue.SimpleQueue | None = None) -> Takeover:
    """One Takeover for the session's TakeoverPairs (the first pair's rig-file config), kept on the target
    (target.takeover: what a UI shows and presses); keys: the queue its key presses come through."""
    tk = Takeover(ts.pairs[0].cfg.takeover, target, len(ts.pairs), ts.recording)
    if keys is not None:
        tk.keys = keys
    for i, pair in enumerate(ts.pairs):
        pair.attach(tk, i)
    target.takeover = tk
    return tk
