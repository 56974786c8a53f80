"""Collecting scripted demonstrations of a twin task through the full teleop stack (SIMULATED).

    rig = task_rig("sim-piper", "peg-insert")            # the rig with the task's scene, cameras, gripper map
    with open_rig(rig, clock="lockstep", seed=0) as s:
        ts = TeleopSession(s, TeleopOptions(mode="next", checkpoint=...))
        ts.record(out, path=...)                            # one MCAP for the session
        ep = EpisodeDriver(ts, get_task("peg-insert"), episodes=50, seed=0)
        ts.hooks.append(ep.on_tick)                         # the operator's hand + detectors, every tick
        ts.loop.run()                                       # ends itself after the last episode
        ep.results                                          # EpisodeResult per episode

The hook runs on the loop's thread: it applies the operator's hand to the twin's leader (joints and trigger),
lets the script decide every DECIDE_EVERY ticks from what it sees (the twin's state) and feels (the leader's
feedback torque), updates the task's stage detectors, marks stages in the recording (progress events) and
ends each episode with its outcome (success / failure: failed demonstrations are kept, labelled). Between
episodes the objects are put back for the next seed, as an assistant would (the arm is clear above them);
after a failed episode the operator first brings the arm back to where the collection started (state "home",
through the leader and the safety layer, outside any recorded episode), as a person re-homes it.
The bookkeeping (placing, detecting, recording, outcome) is TaskEpisodes (factr2_teleop/session/
task_episodes.py), shared with the policy rollout (session/rollout_episodes.py): the scripted operator and a
policy are two drivers of it.
"""

from __future__ import annotations

import numpy as np

from factr2_teleop.session.task_episodes import SETTLE_S, TaskEpisodes
from factr2_teleop.tasks import script_for
from factr2_teleop.tasks.operator import DECIDE_EVERY, Operator, Percept, percept
from factr2_teleop.tasks.scripts import go_joints, wait
from factr2_teleop.tasks.seen import OperatorView
from factr2_teleop.teleop.virtual_operator import felt_joints
from hardware import sim_cpu
from hardware.sim.tasks import Task

HOME_S = 3.0  # s: the least a re-homing move takes (joint speed capped: scripts.joint_move_s)


class EpisodeDriver(TaskEpisodes):
    """The per-tick hook: operator + script + detectors + episode bookkeeping (see the module doc)."""

    def __init__(self, ts, task: Task, episodes: int, seed: int = 0, on_episode=None,
                 perception: bool = False, perturb=None):
        """perception: the operator sees the objects through the simulated pose detector (the perceived
        poses, seen.py), not the twin's truth. perturb: a teleop.perturb.PerturbConfig, the follower's
        target offset in windows drawn from each episode's seed while it runs (None: no perturbation)."""
        from hardware.arms.dynamics import ArmDynamics

        super().__init__(ts, task, episodes, seed, on_episode)
        self.perception = bool(perception)
        self.view = OperatorView()
        self.params_seen: dict = {}  # the episode params as the operator sees them (updated in place)
        self._obs_true: dict = {}  # the twin's truth at this decision: recorded, judged; not the operator's
        fname = self.pair.follower.name
        dyn = ArmDynamics(self.ts.session.rig.device(fname).arm)
        lim = self.pair.follower.safety.limits
        self._op_args = (dyn.fk, dyn.jacobian, lim.q_min, lim.q_max, self.pair.map.backward,
                         self.pair.dt_s)
        self.op: Operator | None = None
        self._q_home: np.ndarray | None = None  # follower joints [rad] the first episode started from
        self._homing = None
        self.perturb = perturb

    # -- the hook ----------------------------------------------------------------------------------------
    def on_tick(self, r) -> None:
        with sim_cpu.simulated():  # the simulated operator and the twin's detectors: not the app's CPU
            self._on_tick(r)

    def _on_tick(self, r) -> None:
        self._k += 1
        if self._state == "done":
            return
        if self._state == "wait":
            if r.phase == "coupled":
                self._begin_episode(r)
            else:
                self._hold(r)
            return
        op = self.op
        if self._state == "home":
            if self._k % DECIDE_EVERY == 0:
                try:
                    next(self._homing)
                except StopIteration:
                    self._start_episode(r)
                    return
                op.decide(self._percept(r), DECIDE_EVERY * self.pair.dt_s)
            self._apply_hand(r)
            return
        if self._k % DECIDE_EVERY == 0:
            self.perceive(r.t)
            p = self._percept(r)
            if self._state == "settle":
                op.decide(p, DECIDE_EVERY * self.pair.dt_s)
                if r.t - self._t_state >= SETTLE_S:
                    self._state = "run"
                    self.rec_start()
                    self._start_perturbation(r.t)
            else:
                op.p = p  # what the script sees at this decision
                self._log_objects(r.t, self._obs_true)
                self._log_perceived(r.t)
                try:
                    next(self.script)
                except StopIteration as stop:
                    self._end_episode(r, stop.value or {})
                    return
                op.decide(p, DECIDE_EVERY * self.pair.dt_s)
                self._detect(r.t, p)
                if r.t - self._t_state > self.task.episode_s:
                    self._end_episode(r, {**getattr(op, "log", {}), "gave_up": True, "timeout": True})
                    return
        self._apply_hand(r)

    # -- pieces ------------------------------------------------------------------------------------------
    def _start_perturbation(self, t: float) -> None:
        """The episode's perturbation from its seed, from t [s] on; the pair adds it before the safety layer
        (the operator then corrects it: it servoes on the follower's joints, operator.py servo_update)."""
        if self.perturb is not None:
            from factr2_teleop.teleop.perturb import Perturbation

            self.pair.perturb = Perturbation(self.perturb, self._ep_seed, self.pair.follower.n_joints, t,
                                             self.task.episode_s + 1.0)

    def _end_episode(self, r, info: dict) -> None:
        self.pair.perturb = None  # between episodes the follower tracks the leader as it is
        super()._end_episode(r, info)

    def _hold(self, r) -> None:
        """Before coupling: the hand keeps the leader where it is (gravity compensation does the rest)."""
        self.twin.bank(self.lname).set_hand_torque(np.zeros(self.pair.leader.n_joints + 1))

    def _apply_hand(self, r) -> None:
        bank = self.twin.bank(self.lname)
        q_l, qd_l = felt_joints(r.leader, bank)
        bank.set_hand_torque(self.op.torques(q_l, qd_l, r.leader.gripper_pos))

    def _percept(self, r) -> Percept:
        """What the operator has now: the twin's objects, or with perception what the detector reports."""
        obs = self._obs_true = self.task.observe(self.model, self.data, self.params)
        p = percept(r, self.data, self.ee_site, obs)
        p.seen = dict(self.seen)
        if self.perception:
            if self.detector is None:
                from hardware.errors import UserError

                raise UserError(f"task {self.task.name} names no detectable objects", where="--perception",
                                fix="collect it without --perception (the operator then sees the truth)")
            p.obs, seen_params = self.view.look(obs, self.params, self.seen, p.T_ee)
            self.params_seen.update(seen_params)
        return p

    def _begin_episode(self, r) -> None:
        """After a failed episode the arm may be anywhere (pressed into the table, on a wrong branch): the
        operator brings it home first (open hand, no lean), then the next episode's scene is set."""
        if self.results and self.results[-1].outcome != "success" and self.op is not None:
            self.op.grip, self.op.servo_on, self.op.b = 0.0, True, np.zeros_like(self.op.b)
            self.op.nudge = np.zeros(2)
            self._homing = _chain(go_joints(self.op, self._q_home, HOME_S), wait(self.op, SETTLE_S))
            self._state = "home"
            return
        self._start_episode(r)

    def _start_episode(self, r) -> None:
        rng = self._reset_episode()
        q0 = self.pair.map.forward(r.leader.q)
        if self.op is None:
            self.op = Operator(*self._op_args, q_start=q0)
            self._q_home = np.asarray(q0, float).copy()
        self.op.grip, self.op.servo_on, self.op.log = 0.0, True, {}
        self.view.reset()
        self.params_seen.clear()
        self.perceive(r.t)
        self.op.p = self._percept(r)
        params = self.params_seen if self.perception else self.params
        self.script = script_for(self.task.name)(self.op, params, rng)
        self._state, self._t_state = "settle", r.t

    def _detect(self, t: float, p: Percept) -> None:
        self._detect_obs(t, self._obs_true)  # stages are judged from the twin's truth, never from the view


def _chain(*gens):
    for g in gens:
        yield from g
