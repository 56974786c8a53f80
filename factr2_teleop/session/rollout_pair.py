"""The arm pair of a policy rollout and the policy's per-tick follower target (the shell around the pure
scheduling in policies/rollout/schedule.py).

RolloutPair is built by the session layer exactly like a teleop pair (build_pairs: the rig's [teleop] table,
the feedback mode and its estimator) and ticked by the same TeleopLoop; only the law differs: the follower
gets target_fn's target, through Follower.command (the role's safety layer: position limits, rate limit,
non-finite rejection) after the pair's coupled-phase rate limit, and the leader is passive (zero torque).
When target_fn has no target, the follower holds (Follower.hold: the safe state) and the pair says why once.

PolicyTarget is that target_fn: per episode, home (a jerk-limited move to the start pose, gripper open) ->
settle -> run (observations to the PolicyRunner at its request period, chunks into the ChunkSchedule, the
interpolated target out); its owner (session/rollout.py) moves it between phases.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from factr2_teleop.teleop.pair import COUPLED, HOLD, LOOP_GAP_SOFT_S, ArmPair, PairHold, _fresh
from factr2_teleop.teleop.pair import IDLE as NOT_BEGUN
from factr2_teleop.teleop.record import TickRecord
from factr2_teleop.teleop.soft_start import rate_limit
from hardware.errors import DeviceError
from hardware.features import IMAGES, follower_values
from hardware.reasons import Reason
from hardware.recording.schemas import TASK_OBJECTS_FEATURE
from hardware.types import STATUS_IMPLAUSIBLE, STATUS_STALE, FollowerCommand
from policies.rollout.schedule import ChunkSchedule, PolicyHold

HOME, SETTLE, RUN, IDLE = "home", "settle", "run", "idle"
# s: in real time an observation waits for frames at most this old (a camera that stopped, or a twin camera's
# render process still warming up: the policy must not see the arm as it was)
FRAME_MAX_AGE_S = 0.1
# s: the passive leader is read and re-sent zero torque this often, not every tick: it takes no part in the
# law, and its reads and writes were 40 % of a rollout tick's CPU (2 Dynamixel bus transactions). 20 ms keeps
# both its watchdog (hardware/safety.py DEFAULT_WATCHDOG_S, 50 ms) and its recorded pose (the recording's
# 30 Hz frames) fed.
LEADER_SERVICE_PERIOD_S = 0.02


class RolloutPair(ArmPair):
    """ArmPair whose follower follows target_fn(now [s], follower JointState) -> (q (n,) [rad] or None,
    gripper [m] or None, why None: a PolicyHold reason); the leader gets zero torque. holds: hold entries
    by the reason's key (PolicyHold values; waiting kinds are not counted).
    serve_leader=False: after begin() the passive leader is neither read nor re-sent its zero torque (a
    lockstep twin's leader that nothing records or shows; its safe exit still goes through its safety
    layer); the follower's law never reads the leader, so this changes no follower command."""

    serve_leader = True
    slow_resume = False  # after a loop gap the follower comes back slowly (_note_loop_gap)
    _gap_t = None  # [s] the tick that ended a loop gap, until a follower sample from then on arrives

    @staticmethod
    def target_fn(now: float, fs):  # follow() attaches the rollout's PolicyTarget
        return None, None, Reason.of(PolicyHold.NO_POLICY)

    def rest_leader(self) -> None:
        """Stop serving the passive leader after begin() (see the class doc); the twin's leader idles. The
        leader rests (Leader.rest: zero torque, its servos' watchdog stood down for the silence) at begin(),
        or now when begun."""
        self.serve_leader = False
        if self.phase != NOT_BEGUN:
            self.leader.rest("policy rollout: the leader is passive and rested")

    def follow(self, target_fn) -> None:
        """Attach the target: target_fn(now [s], follower JointState) -> (q, gripper, why)."""
        self.target_fn = target_fn

    def begin(self, clock=None) -> None:
        """Wait for fresh data from both arms (as the first tick demands: ArmPair.begin); the leader passive,
        the follower held where it is."""
        clock = clock or self.leader.clock
        t_begin = clock.now()
        t_end = t_begin + self.cfg.start_timeout_s
        while True:
            now = clock.now()
            ls, fs = self.leader.read(), self.follower.read()
            if (_fresh(ls, now, self.cfg.leader_stale_s, t_begin)
                    and _fresh(fs, now, self.cfg.follower_stale_s, t_begin)):
                break
            if clock.now() >= t_end:
                self.make_safe(Reason.of(PairHold.NO_DATA_AT_START))
                raise DeviceError(f"no fresh joint data within {self.cfg.start_timeout_s:.1f} s",
                                  where=self.cfg.name,
                                  fix="check power, cables and the port/channel in the rig")
            clock.sleep(self.dt_s)
        self._t_ok = {"leader": ls.t, "follower": fs.t}
        self.q_home = np.asarray(fs.q, dtype=float).copy()
        if self.serve_leader:
            self.leader.zero_torque("policy rollout: the leader is passive")
        else:  # told nothing more until the end's zero torque
            self.leader.rest("policy rollout: the leader is passive and rested")
        self.follower.hold("policy rollout: waiting")
        self.phase = HOLD
        self.holds: Counter = Counter()  # holds by reason key (entries and changes of reason kind)
        self._hold_why: PolicyHold | None = None
        self._t_leader = -np.inf
        self._zero_tau = np.zeros(self.leader.n_joints)  # one per pair: every tick's record shares it
        self._zero_tau.flags.writeable = False

    def _note_loop_gap(self, now: float) -> None:
        """Before a tick's reads: a tick more than LOOP_GAP_SOFT_S after the last means the app itself was
        stopped (SIGSTOP, a sleeping host) and its motors fell back by themselves meanwhile (docs/safety.md:
        a YAM sinks on its damping). As teleop's pair does, the follower then comes back at the soft start's
        speed (SoftStartConfig.v_max_rad_s), from where it is, not at the coupled rate limit from its old
        target, until its target reaches the one it is given (_rate_now, _caught_up)."""
        gap = now - self._t_prev if math.isfinite(self._t_prev) else 0.0
        if gap > LOOP_GAP_SOFT_S:
            self.slow_resume, self._gap_t = True, now
            self.q_target = None  # from where the arm is now (it may have sunk), not from the old target
            self._say(f"the loop did not run for {gap * 1e3:.0f} ms (the app was stopped); the follower "
                      f"comes back at the soft start's {float(self.soft.v.max()):.1f} rad/s")

    def _fresh_since_gap(self, fs) -> bool:
        """After a loop gap only a follower sample taken since, on every joint, counts: the last one from
        before shows the arm where it was before it sank (a Damiao motor answers commands only: none came
        during the gap; a joint whose first answer the encoder check held back is flagged), and a target
        from there would pull it back at once. False (the follower holds) until one arrives."""
        if self._gap_t is None:
            return True
        flagged = np.bitwise_and(np.asarray(fs.status, np.int64), STATUS_STALE | STATUS_IMPLAUSIBLE).any()
        if fs.t >= self._gap_t and not flagged:
            self._gap_t = None
            # the safety layer's rate limit starts from where the arm is now, not from the hold the stale
            # sample set (a target pulled from there snapped a sunk YAM back up at its rate)
            self.follower.hold("after the loop gap: from the measured position")
            return True
        return False

    def _rate_now(self) -> np.ndarray:
        """The follower target's rate limit [rad/s] this tick."""
        return self.soft.v if self.slow_resume else self.soft.rate

    def _caught_up(self, q_goal) -> None:
        """The slow return after a loop gap ends once the target is within done_tol_rad of q_goal [rad]."""
        if self.slow_resume and np.all(np.abs(self.q_target - np.asarray(q_goal, float))
                                       <= self.soft.cfg.done_tol_rad):
            self.slow_resume = False

    def tick(self, now: float) -> TickRecord:
        self._note_loop_gap(now)
        service = self.serve_leader and now >= self._t_leader  # its turn (LEADER_SERVICE_PERIOD_S)
        if service:
            self._t_leader = now + LEADER_SERVICE_PERIOD_S - 0.5 * self.dt_s  # half a tick: no drift to n+1
        dt, ls, fs, leader_ok, follower_ok = self._read_both(now, read_leader=service)
        motor = self._check_samples(ls, fs).get("follower")  # (the passive leader's errors do not matter)
        follower_ok = follower_ok and not motor and self._fresh_since_gap(fs)
        q_ref = self.q_target if self.q_target is not None else fs.q
        if follower_ok:
            self._tick_estimator(now, fs, q_ref)
        zero = self._zero_tau
        tau_sent = self.leader.command_torque(zero) if (leader_ok and service) else zero
        self.sent = None
        if follower_ok:
            q, grip, why = self.target_fn(now, fs)
        else:
            q, grip = None, None
            why = Reason.of(PolicyHold.FOLLOWER_MOTOR_ERROR, what=motor) if motor else \
                Reason.of(PolicyHold.FOLLOWER_STALE)
        if q is None:
            if self.phase != HOLD:
                self.follower.hold(why)
                self.phase = HOLD
            kind = why.kind
            if kind != self._hold_why:  # a hold entered, or its kind of reason changed: said once, counted
                if kind.fault:
                    self.holds[why.key] += 1
                self._say(f"follower on hold: {why}")
            self._hold_why = kind
            self.q_target = None
        else:
            prev = self.q_target if self.q_target is not None else np.asarray(fs.q, dtype=float)
            self.q_target = rate_limit(np.asarray(q, dtype=float), prev, self._rate_now(), dt)
            self._caught_up(q)
            self.sent = self.follower.command(FollowerCommand(q=self.q_target, gripper=grip))
            self._hold_why = None
            if self.phase != COUPLED:
                self.phase = COUPLED
                self._say("follower follows the policy's schedule", logging.INFO)
        self.last = self._record(now, ls, fs, tau_sent, None)
        return self.last


@dataclass
class TargetArm:
    """One follower the policy moves: its pair, recorded arm name ("follower", "left_follower"), where its
    joint targets sit in the action vector (q [rad]: columns q; gripper [m]: column grip, None without one),
    the range its gripper target is clamped to [m], and the gripper opening it homes to [m] (None: as is)."""

    pair: RolloutPair
    arm: str
    q: slice
    grip: int | None
    gripper_range: tuple[float, float] = (-np.inf, np.inf)
    gripper_open: float | None = None


class PolicyTarget:
    """The follower targets of a rollout, tick by tick, for every arm the policy moves (one per rig pair).

    Each pair asks for its own target with `for_pair(i)` (its follow()); the first to ask at a tick's time
    computes the tick's action for all arms (one observation of every follower, one schedule target) and the
    others take their columns of it. runner: policies.rollout.PolicyRunner (started); schedule: ChunkSchedule
    over the whole action vector; features: the rig's (hardware.features.rig_features): the observation is
    read by the names the checkpoint stores; frames: callable(now) -> {camera: RGB frame of now} or None
    while they are not there. The episode owner moves it between phases; on a twin task it hands run() the
    callable that gives the PRIVILEGED object vector."""

    def __init__(self, arms: list[TargetArm], runner, schedule: ChunkSchedule, features: dict, frames):
        self.arms, self.runner, self.schedule = list(arms), runner, schedule
        self.features, self.frames = features, frames
        self.objects = None  # callable -> the object vector (privileged or perceived), from run() (twin task)
        self.state = IDLE
        self.started = False
        self._t_next = -np.inf
        self._tick: tuple = (np.nan, None, None)  # (now [s], action (A,) or None, why)
        self._home_done = [False] * len(self.arms)
        self.ages_s: list[float] = []  # age of the executed action per run tick [s]
        self._q_cols = np.concatenate([np.arange(a.q.start, a.q.stop) for a in self.arms])
        lims = [a.pair.follower.safety.limits for a in self.arms]
        self._q_min = np.concatenate([np.asarray(lim.q_min) for lim in lims])
        self._q_max = np.concatenate([np.asarray(lim.q_max) for lim in lims])
        self.clamped = 0  # run ticks whose target lay outside the joint limits (the safety layer clamped it)
        self.takeover = None  # session/takeover_switch.Takeover when the operator may take over

    def for_pair(self, i: int):
        """The target function of pair i: (now [s], its follower JointState) -> (q [rad] or None, gripper
        [m] or None, why None)."""
        return lambda now, fs: self._target(i, now, fs)

    # -- phases (the owner calls these) -----------------------------------------------------------------
    def home(self, fs=None) -> None:
        """Every arm to its start pose (a jerk-limited move from where it is); fs: the first pair's sample."""
        self.started = True
        for i, a in enumerate(self.arms):
            q = fs.q if (i == 0 and fs is not None) else a.pair.follower.last_state.q
            a.pair.soft.reset(np.asarray(q, dtype=float))
        self._home_done = [False] * len(self.arms)
        self.state = HOME

    @property
    def at_home(self) -> bool:
        return all(self._home_done)

    def settle(self) -> None:
        self.state = SETTLE

    def run(self, now: float, objects=None, seed: int | None = None) -> None:
        """The policy drives from `now`; objects: callable -> the PRIVILEGED object vector (a twin task);
        seed: the episode's, the sampler's noise drawn from it (an episode repeats on its own)."""
        self.objects = objects
        if seed is not None:
            self.runner.reseed(seed)
        self.runner.take()  # chunks of an earlier episode are dropped
        self.schedule.clear()
        self._t_next = now
        self._tick = (np.nan, None, None)
        self.state = RUN

    def idle(self) -> None:
        self.state = IDLE

    def replan(self, now: float) -> None:
        """The operator handed back at `now` [s]: every chunk asked for before is dropped (the schedule
        refuses them, one still in inference included) and a fresh observation is asked for at once: the
        policy re-plans from the arm's state, no stale chunk is executed."""
        self.runner.take()
        self.schedule.restart(now)
        self._t_next = now
        self._tick = (np.nan, None, None)

    # -- per tick ------------------------------------------------------------------------------------------
    def _target(self, i: int, now: float, fs):
        arm = self.arms[i]
        if self.state == HOME:
            q, done = arm.pair.soft.step(arm.pair.q_home)
            self._home_done[i] = self._home_done[i] or bool(done)
            return q, arm.gripper_open, None
        if self.state == SETTLE:
            return arm.pair.q_home, arm.gripper_open, None
        if self.state != RUN:
            waiting = PolicyHold.BETWEEN_EPISODES if self.started else PolicyHold.NOT_STARTED
            return None, None, Reason.of(waiting)
        if self._tick[0] != now:
            self._tick = (now, *self._action(now, i, fs))
        _, a, why = self._tick
        if a is None:
            return None, None, why
        lo, hi = arm.gripper_range
        grip = float(min(max(a[arm.grip], lo), hi)) if arm.grip is not None else None
        return a[arm.q], grip, None

    def _action(self, now: float, i: int, fs):
        """The tick's whole action vector (or None and why: a PolicyHold reason), the first time a pair asks
        at `now`."""
        if now >= self._t_next:
            obs = self.observation(now, {i: fs})
            if obs is not None:
                self.runner.submit(obs, now)  # inline (lockstep): the chunk is ready below
                self._t_next = now + self.schedule.period_s
        for c in self.runner.take():
            self.schedule.add(c)  # a refused chunk holds via target() below, with the reason
        a, why, age = self.schedule.target(now)
        if a is None:
            return None, why
        self.ages_s.append(age)
        q = a[self._q_cols]
        # ndarray methods, not np.any: the same values at a third of the CPU per tick
        self.clamped += int(bool((q < self._q_min).any() or (q > self._q_max).any()))
        return a, None

    def observation(self, now: float, samples: dict | None = None) -> dict | None:
        """The flat observation now, by feature name (None while a camera the policy needs has no frame of
        the last FRAME_MAX_AGE_S). samples: the followers' JointStates this tick by pair index (the others:
        their newest sample, as their own tick read it: the bus is not read twice)."""
        obs: dict = {}
        for i, arm in enumerate(self.arms):
            fs = (samples or {}).get(i)
            fs = fs if fs is not None else arm.pair.follower.last_state  # its tick reads the bus
            est = arm.pair.estimate
            tau = est.tau_ext if est is not None else np.full(arm.pair.follower.n_joints, np.nan)
            obs.update(follower_values(self.features, arm.arm, fs, tau))
        if self.runner.cameras:
            frames = self.frames(now)
            if frames is None:
                return None
            obs.update({f"{IMAGES}{c}": rgb for c, rgb in frames.items()})
        if self.runner.uses_objects:
            obs[getattr(self.runner, "object_feature", TASK_OBJECTS_FEATURE)] = self.objects()
        return obs
