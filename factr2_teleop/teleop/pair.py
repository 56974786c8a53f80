"""One leader/follower pair: the per-tick state machine the loop drives (thin shell over the pure laws).

Phases: soft_start (follower moves to the leader's mapped pose, no feedback) -> coupled (follower tracks, the
leader gets the full law) ; hold (leader or follower data stale, or a resumed leader too far away: follower
holds, leader gets zero torque if its data is stale, gravity compensation otherwise) -> soft_start again once
both are fresh and close enough ; fault / stopped (both safe: leader zero torque, follower hold).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np

from calibration.estimate import FLAG_NONFINITE, Estimate
from calibration.estimators import Estimator, EstimatorInput
from factr2_teleop.teleop.feedback import contact_score
from factr2_teleop.teleop.hold_checks import (  # noqa: F401 -- PairHold, _fresh, status_bits: imported from here
    _ERROR_BITS,
    _STALE_BITS,
    PairHold,
    _complete,
    _fresh,
    device_notes,
    motor_errors,
    status_bits,
)
from factr2_teleop.teleop.leader_law import LeaderInputs, LeaderLaw
from factr2_teleop.teleop.mapping import JointMap
from factr2_teleop.teleop.pair_config import PairConfig
from factr2_teleop.teleop.record import TickRecord
from factr2_teleop.teleop.soft_start import SoftStart, mismatch_error
from hardware.clock import Clock
from hardware.errors import DeviceError
from hardware.reasons import Reason
from hardware.roles import Follower, Leader, make_safe
from hardware.safety import SafeFollowerCommand
from hardware.small_vec import all_finite
from hardware.types import FollowerCommand, JointState

log = logging.getLogger("factr2.teleop")

SOFT_START, COUPLED, HOLD, FAULT, STOPPED, IDLE = "soft_start", "coupled", "hold", "fault", "stopped", "idle"
LOOP_GAP_SOFT_S = 1.0  # s: a tick this late means the app itself stopped (its motors fell back by themselves
# meanwhile, docs/safety.md): the pair holds and re-couples through the soft start; shorter holds (a bus-off,
# a lost read) re-couple directly when close (SoftStartConfig.resume_direct_rad)
# reads in a row without a new complete sample before old data holds: a loop that was itself late (a stall on
# a slow core) and missed one read does not hold while data keeps arriving; silence still holds within
# leader_stale_s / follower_stale_s (pair_config.DEFAULT_STALE_S: 10 reads at 500 Hz)
STALE_MIN_MISSES = 2
_NAN = float("nan")


class ArmPair:
    """Leader + follower + law + map + soft start + estimator. The loop calls begin() once, then tick()."""

    def __init__(self, leader: Leader, follower: Follower, cfg: PairConfig, dt_s: float,
                 gravity_fn: Callable | None = None, jacobian_fn: Callable | None = None,
                 model_map: JointMap | None = None,
                 estimator: Estimator | None = None, mode: str | None = None):
        self.leader, self.follower, self.cfg, self.dt_s = leader, follower, cfg, float(dt_s)
        self.law = LeaderLaw(cfg.law, leader.safety.limits, gravity_fn, jacobian_fn, model_map)
        self.map = JointMap(cfg.mapping, leader.n_joints, follower.n_joints, where=f"{cfg.name}.mapping")
        self.soft = SoftStart(cfg.soft_start, follower.n_joints, dt_s)
        self.estimator = estimator
        self.mode = mode or ("none" if estimator is None else "custom")  # feedback mode name (session.pairs)
        self.phase = IDLE
        self.q_target: np.ndarray | None = None
        self.estimate: Estimate | None = None
        self._t_est_run = -np.inf
        self._t_prev = float("nan")
        self.messages: list[str] = []  # drained by the loop each tick
        self._last_msg = ""
        self.estimator_errors = 0
        self._estimator_down = False  # feedback off after an estimator error, until a valid estimate again
        self.last: TickRecord | None = None
        self.sent: SafeFollowerCommand | None = None  # what reached the follower this tick
        # DART-style collection (teleop/perturb.py): t [s] -> offset [rad] added to the coupled target
        # before the follower's safety layer; None: none
        self.perturb: Callable[[float], np.ndarray] | None = None
        self._offset: np.ndarray | None = None  # this tick's offset asked [rad] (recorded)
        self._t_ok = {"leader": -np.inf, "follower": -np.inf}  # time of the last complete sample [s]
        self._misses = {"leader": 0, "follower": 0}  # reads in a row without a new complete sample
        self._leader_ok = False
        self._refused = False  # a resume is refused (mismatch): said once, not every tick
        self._after_gap = False  # the loop itself stopped (LOOP_GAP_SOFT_S): the next resume soft-starts
        # holds entered, time spent in them [s], resumes refused (once per refusal): the demo's summary
        self.holds, self.hold_s, self.resume_refusals = 0, 0.0, 0
        self._jumps = {"leader": 0, "follower": 0}  # implausible jumps already said (safety.jumps_rejected)
        self._turns = {"leader": 0, "follower": 0}  # turns unwrapped already said (Device.turns_unwrapped)
        self._facts = {"leader": (None, False, 0), "follower": (None, False, 0)}  # _facts_of
        self._devices = {"leader": leader, "follower": follower}
        self._tau_back: tuple = (None, None, 0.0)  # (estimate array, mapped to the leader, contact score)

    # -- helpers -------------------------------------------------------------------------------------
    def _say(self, text: str, level: int = logging.WARNING) -> None:
        if text != self._last_msg:  # a repeated condition is said once
            self._last_msg = text
            self.messages.append(text)
            log.log(level, "%s: %s", self.cfg.name, text)

    def _enter_hold(self, reason: Reason, leader_ok: bool) -> None:
        self.follower.hold(reason)
        self.phase = HOLD
        self.holds += 1
        if not leader_ok:
            try:  # a leader that stopped answering may also refuse the write; the follower is held already
                self.leader.zero_torque(reason)
            except Exception as e:  # noqa: BLE001
                self._say(f"leader zero torque failed ({type(e).__name__}: {e})")
        self._say(f"follower on hold: {reason}")

    def _start_soft(self, ls: JointState, fs: JointState, resume: bool = False) -> bool:
        goal = self.map.forward(ls.q)
        err = mismatch_error(fs.q, goal, self.soft.max_mismatch, where=self.cfg.name)
        if err is not None:
            if not self._refused:  # the numbers change every tick: say it once per refusal
                self._say(str(err))
                self.resume_refusals += 1
            self._refused = True
            return False
        self._refused = False
        self.law.feedback.reset()
        direct = self.cfg.soft_start.resume_direct_rad
        after_gap, self._after_gap = self._after_gap, False
        if resume and direct > 0 and not after_gap and bool(np.all(np.abs(goal - fs.q) <= direct)):
            self.q_target = np.asarray(fs.q, dtype=float).copy()  # coupled_step() closes the gap from here
            self.phase = COUPLED
            self._say("re-coupled after hold", logging.INFO)
            return True
        self.soft.reset(fs.q)
        self.q_target = None
        self.phase = SOFT_START
        return True

    def make_safe(self, reason: Reason | str) -> None:
        """Leader zero torque, follower hold; each attempted even if the other fails (hardware.roles)."""
        errors = make_safe([self.leader], [self.follower], reason)
        if errors:
            log.error("%s: could not make an arm safe: %s", self.cfg.name, errors)

    def set_rate(self, rate_hz: float) -> None:
        """Run at a new loop rate (the loop degraded, teleop/degrade.py): the period, the soft start's step,
        and the feedback gains scaled with the rate (a sampled force-feedback loop's stable gain falls with
        its period)."""
        ratio = float(rate_hz) * self.dt_s  # new rate / old rate
        self.dt_s = 1.0 / float(rate_hz)
        self.law.feedback.gain = self.law.feedback.gain * ratio
        self.soft = SoftStart(self.cfg.soft_start, self.follower.n_joints, self.dt_s)
        if self.phase == SOFT_START:  # go on from the target it reached
            self.soft.reset(self.q_target if self.q_target is not None else self.follower.last_state.q)

    @property
    def resume_refused(self) -> bool:
        """On hold and the resume refused: the leader is too far from the follower (the operator brings it
        back; the pair resumes by itself once it is within soft_start.max_mismatch_rad)."""
        return self.phase == HOLD and self._refused

    # -- lifecycle ------------------------------------------------------------------------------------
    def begin(self, clock: Clock | None = None) -> None:
        """Wait for fresh data from both arms, refuse a large mismatch (UserError), start the soft start.

        Fresh means a sample taken since begin() was called and within what the first tick will demand
        (leader_stale_s / follower_stale_s), not merely "some data within start_timeout_s": a sample cached at
        connect time passed the old test, and the first tick then put the follower on hold ("follower data
        stale (23-71 ms old)" in 2-3 of 10 twin starts).
        clock: the loop's clock (it may be the one that steps a twin); default the leader driver's."""
        clock = clock or self.leader.clock
        t_begin = clock.now()
        t_end = t_begin + self.cfg.start_timeout_s
        while True:
            now = clock.now()
            ls, fs = self.leader.read(), self.follower.read()
            l_ok = _fresh(ls, now, self.cfg.leader_stale_s, since=t_begin)
            f_ok = _fresh(fs, now, self.cfg.follower_stale_s, since=t_begin)
            if l_ok and f_ok:
                break
            if now >= t_end:
                who = " and ".join(x for x, ok in (("leader", l_ok), ("follower", f_ok)) if not ok)
                self.make_safe(Reason.of(PairHold.NO_DATA_AT_START))
                raise DeviceError(f"no fresh joint data from the {who} within "
                                  f"{self.cfg.start_timeout_s:.1f} s",
                                  where=self.cfg.name,
                                  fix="check power, cables and the port/channel in the rig")
            clock.sleep(self.dt_s)
        self._t_ok = {"leader": ls.t, "follower": fs.t}
        self.law.reset(ls.q)  # null-space posture = the leader's start pose unless the rig sets one
        err = mismatch_error(fs.q, self.map.forward(ls.q), self.soft.max_mismatch, where=self.cfg.name)
        if err is not None:
            self.make_safe(Reason.of(PairHold.START_MISMATCH))
            self.phase = STOPPED
            raise err
        self._start_soft(ls, fs)

    def tick(self, now: float) -> TickRecord:
        """One control period. Returns the record of this tick (also kept as self.last)."""
        if self.phase == HOLD and math.isfinite(self._t_prev):
            self.hold_s += now - self._t_prev  # the time since the last tick was spent on hold
        gap = now - self._t_prev if math.isfinite(self._t_prev) else 0.0
        if gap > LOOP_GAP_SOFT_S and self.phase in (COUPLED, SOFT_START, HOLD):
            # the app was stopped: the motors fell back by themselves (docs/safety.md) and the operator's arm
            # went on; hold, then come back at the soft start's speed, not the coupled rate limit's
            self._after_gap = True
            if self.phase != HOLD:
                self._enter_hold(Reason.of(PairHold.LOOP_GAP, gap_ms=gap * 1e3), leader_ok=True)
        dt, ls, fs, leader_ok, follower_ok = self._read_both(now)
        errors = self._check_samples(ls, fs)
        if errors:
            leader_ok = leader_ok and "leader" not in errors
            follower_ok = follower_ok and "follower" not in errors
        q_leader_f = self.map.forward(ls.q)
        if follower_ok:
            self._tick_estimator(now, fs, q_leader_f)
        if not (leader_ok and follower_ok):
            if self.phase != HOLD:
                who = "leader" if not leader_ok else "follower"
                if who in errors:
                    reason = Reason.of(PairHold.MOTOR_ERROR, who=who, what=errors[who])
                else:
                    age = (now - self._t_ok[who]) * 1e3 if np.isfinite(self._t_ok[who]) else float("inf")
                    reason = Reason.of(PairHold.DATA_STALE, who=who, age_ms=age)
                self._enter_hold(reason, leader_ok)
        elif self.phase == HOLD:
            self._start_soft(ls, fs, resume=True)
        out = None
        if leader_ok:  # the law needs a fresh leader pose; feedback only while coupled
            out = self.law.step(self._leader_inputs(now, ls, fs), feedback_on=self.phase == COUPLED)
            if out.message:
                self._say(out.message)
            tau_sent = self.leader.command_torque(out.tau)
        else:
            tau_sent = np.zeros(self.leader.n_joints)
        self.sent = None
        offset = None if self.perturb is None else np.zeros(self.follower.n_joints)
        if self.phase == SOFT_START:
            self.q_target, done = self.soft.step(q_leader_f)
            self.sent = self.follower.command(FollowerCommand.targets(self.q_target))
            if done:
                self.phase = COUPLED
                self._say("coupled: follower tracks the leader", logging.INFO)
        elif self.phase == COUPLED:
            prev = self.q_target if self.q_target is not None else fs.q
            self.q_target = self.soft.coupled_step(q_leader_f, prev, dt)
            grip = self.map.gripper_forward(ls.gripper_pos)
            q_cmd = self.q_target  # the operator's target; a perturbation offsets what is sent, not it
            if offset is not None:
                offset = np.asarray(self.perturb(now), dtype=float)
                q_cmd = q_cmd + offset
            self.sent = self.follower.command(FollowerCommand.targets(q_cmd, grip))  # the safety layer
        self._offset = offset
        self.last = self._record(now, ls, fs, tau_sent, out)
        return self.last

    # -- pieces ---------------------------------------------------------------------------------------
    def _read_both(self, now: float, read_leader: bool = True
                   ) -> tuple[float, JointState, JointState, bool, bool]:
        """The start of every tick (teleop and rollout pairs): this tick's dt [s] (clamped to 0..3 periods),
        both arms' states, and whether each is fresh. read_leader=False (a rollout's passive leader between
        its service ticks) keeps the leader's last state and verdict."""
        dt = now - self._t_prev if math.isfinite(self._t_prev) else self.dt_s
        dt = min(max(dt, 0.0), 3.0 * self.dt_s)
        self._t_prev = now
        if read_leader:
            ls = self.leader.read()
            self._leader_ok = self._ok("leader", ls, now, self.cfg.leader_stale_s)
        else:
            ls = self.leader.last_state
        fs = self.follower.read()
        return dt, ls, fs, self._leader_ok, self._ok("follower", fs, now, self.cfg.follower_stale_s)

    def _check_samples(self, ls: JointState, fs: JointState) -> dict[str, str]:
        """Say each implausible jump a device held (Device.read); return who reports a motor error and what
        ({} when none: the usual tick, the status bits _ok found)."""
        for text, level in device_notes(self._devices, self._jumps, self._turns):
            self._say(text, level)
        out = {}
        for who, st in (("leader", ls), ("follower", fs)):
            if self._facts_of(who, st)[2] & _ERROR_BITS:
                what = motor_errors(st)
                if what:
                    out[who] = what
        return out

    def _facts_of(self, who: str, st: JointState) -> tuple:
        """(the sample, its q all finite, its status bits), once per sample: a follower's sample is the same
        object over the ticks between its frames, and _ok and _check_samples both ask."""
        c = self._facts[who]
        if c[0] is not st:
            c = self._facts[who] = (st, all_finite(st.q), status_bits(st))
        return c

    def _ok(self, who: str, st: JointState, now: float, max_age: float) -> bool:
        """Fresh: finite, and a complete sample within max_age (a lost read now and then is tolerated,
        silence is not: it holds the follower within max_age + one tick)."""
        _, finite, bits = self._facts_of(who, st)
        if finite and math.isfinite(st.t) and now - st.t <= max_age and not bits & _STALE_BITS:
            self._t_ok[who] = st.t
            self._misses[who] = 0
        else:
            self._misses[who] += 1
        return finite and (now - self._t_ok[who] <= max_age or self._misses[who] < STALE_MIN_MISSES)

    def _tick_estimator(self, now: float, fs: JointState, q_leader_f: np.ndarray) -> None:
        est = self.estimator
        if est is None:
            return
        period = max(self.cfg.estimator_period_s, est.period_s)
        try:
            if now - self._t_est_run < period:
                est.idle()  # spread the estimator's work over the ticks between its samples
                if self.estimate is not None and self.estimate.valid:
                    new = est.refresh(self._input(now, fs, q_leader_f))  # this tick vs the last model
                    if new is not None:
                        self.estimate = new
                return
            self._t_est_run = now
            new = est.update(self._input(now, fs, q_leader_f))
        except Exception as e:  # noqa: BLE001 -- a failing estimator turns feedback off, not the arms
            self.estimator_errors += 1
            self.estimate = Estimate(tau_ext=np.full(self.follower.n_joints, np.nan), t=now,
                                     flags=FLAG_NONFINITE)
            self._say(f"feedback off: estimator failed ({type(e).__name__}: {e})")
            self._estimator_down = True
            return
        if new is not None:
            self.estimate = new
            if self._estimator_down and new.valid:  # e.g. a restarted NEXT worker answers again
                self._estimator_down = False
                self._say("feedback back on: the estimator answers again", logging.INFO)

    def _input(self, now: float, fs: JointState, q_leader_f: np.ndarray) -> EstimatorInput:
        sent = self.q_target
        if self._offset is not None and sent is not None:  # what was sent: the perturbed target
            sent = sent + self._offset
        return EstimatorInput(now, fs, q_leader_f, sent)  # positional (t, follower, q_leader_f, q_target_f)

    def _leader_inputs(self, now: float, ls: JointState, fs: JointState) -> LeaderInputs:
        est = self.estimate
        if self.estimator is None or est is None:
            return LeaderInputs(t=now, q=ls.q, q_dot=ls.q_dot, gripper_effort=fs.gripper_effort)
        tau_e, c = est.tau_ext, self._tau_back
        if c[0] is not tau_e:  # mapped once per estimate array (the observer's is the same one, read-only,
            # over the ticks between follower samples)
            tau_f = np.asarray(tau_e, dtype=float)
            if tau_f.shape != (self.follower.n_joints,):
                tau_f = np.full(self.follower.n_joints, np.nan)
            tau_l = self.map.torque_back(tau_f)
            tau_l.flags.writeable = False  # the feedback gate keeps its floats while it is the same
            c = (tau_e, tau_l, contact_score(tau_f))
            if type(tau_e) is np.ndarray and not tau_e.flags.writeable:  # nobody can change it: keep
                self._tau_back = c
        # positional, in the field order (t, q, q_dot, tau_ext_leader, contact_score_nm, est_t, est_fresh,
        # gripper_effort): 500 Hz
        return LeaderInputs(now, ls.q, ls.q_dot, c[1], c[2], est.t, est.valid, fs.gripper_effort)

    def _record(self, now: float, ls: JointState, fs: JointState, tau_sent: np.ndarray, out) -> TickRecord:
        nf = self.follower.n_joints
        est, sent = self.estimate, self.sent
        tau_ext = est.tau_ext if est is not None else np.full(nf, np.nan)
        if type(tau_ext) is not np.ndarray or tau_ext.dtype != np.float64:  # (np.asarray: the same array
            tau_ext = np.asarray(tau_ext, dtype=float)  # when it is one of float64, a new one otherwise)
        if sent is None:
            action_q, grip, hold = np.full(nf, np.nan), _NAN, self.phase in (HOLD, FAULT, STOPPED)
        else:
            action_q, hold = sent.q, bool(sent.hold)
            grip = _NAN if sent.gripper is None else float(sent.gripper)
        if out is None:
            terms, gate, contact, fresh, grip_fb = {}, 0.0, False, False, 0.0
        else:  # the terms read-only, this tick's
            terms, gate, contact, fresh, grip_fb = (out.terms, out.gate, bool(out.contact), bool(out.fresh),
                                                    out.gripper_tau)
        # positional, in the field order (t, pair, phase, leader, follower, leader_tau_cmd, tau_ext, action_q,
        # action_gripper, action_hold, leader_tau_terms, gate, contact, fresh, leader_gripper_tau_fb, then
        # the loop's four at their defaults -- the loop sets them -- and perturb_q): 500 Hz, a dataclass of
        # 20 fields by keyword costs about twice the same call by position
        return TickRecord(now, self.cfg.name, self.phase, ls, fs, tau_sent, tau_ext, action_q, grip, hold,
                          terms, gate, contact, fresh, grip_fb, _NAN, 0, _NAN, _NAN, self._offset)
