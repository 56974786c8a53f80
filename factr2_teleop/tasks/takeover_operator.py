"""The twin's operator during a policy rollout with takeover (issue #33 item 5, SIMULATED).

The scripted operator that collects demonstrations (operator.py, the task scripts) watches the policy drive.
When the task's progress stalls (no new stage for STALL_S: its pre-intervention window) or the follower holds
on a policy fault for HOLD_S, it grabs the leader: its hand (the twin leader's hand torque, as in collection)
pushes the leader toward where the task script wants the arm, the hand torque on the following spring crosses
the takeover threshold, and the follower follows the leader (session/rollout_takeover.py). It finishes the
task through force-feedback teleop with the same script a demonstration uses (from the arm's state: it first
opens and lifts a gripper that holds nothing), then lets go; the hand at rest hands back to the policy. While
its script runs it holds the clutch (Takeover.clutch, as a person would hold a pedal down): the script's
pauses (lining up, waiting) do not hand back. One intervention per episode at most; the episode's time limit
restarts at the grab (the operator needs its time).

    run_rollout(RolloutOptions(..., takeover=True), RolloutHooks(operator=TwinTakeoverOperator))  # --takeover

Hook on the loop's thread, after the pairs' ticks: the hand torque it sets acts in the next physics step.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from factr2_teleop.session.rollout_pair import RUN
from factr2_teleop.tasks import kinematics as K
from factr2_teleop.tasks import script_for
from factr2_teleop.tasks.operator import DECIDE_EVERY, Operator, Percept, percept
from factr2_teleop.tasks.place import RESUMES_HELD
from factr2_teleop.tasks.scripts import grip, move
from factr2_teleop.teleop.pair import HOLD
from factr2_teleop.teleop.takeover import OPERATOR
from factr2_teleop.teleop.virtual_operator import felt_joints
from hardware import sim_cpu

STALL_S = 12.0  # s: no new task stage for this long while the policy drives: the operator steps in. The
# demonstrator itself needs up to 12.5 s for a stage in 90 % of its peg-insert episodes (start -> grasp 6.9 s,
# grasp -> align 10.2, align -> insert 12.5: 50 demonstrations of seed 1); at 6 s the operator took over in
# 19 of 20 episodes of a DAgger round, 6.2 s in, before a slower but working policy had even grasped.
HOLD_S = 0.5  # s: the follower on hold (a policy fault) this long: the operator steps in
PEDAL_AFTER_S = 1.0  # s: a grab the hand detector has not seen by then is confirmed with the pedal (key)
LIFT_M = 0.05  # m: an empty gripper is lifted this much before the script starts over
WATCH, DRIVE, LET_GO = "watch", "drive", "let go"


def finish_script(task_name: str):
    """A script that finishes the task from wherever the arm is. An object already in the hand is carried
    on from where it is (the pick-and-place scripts from their approach: line up and push, as a person
    correcting the policy would; before, the whole demonstration ran again -- lift 7 cm, grasp again -- and
    those corrections taught "start over" where the demonstrations push, docs/takeover.md). Otherwise the
    demonstration script, after opening and lifting a gripper that holds nothing."""
    demo = script_for(task_name)

    def script(op, params, rng):
        touch = op.p.obs.get("finger_touch")
        held = touch is not None and bool(np.all(touch)) and op.grip > 0.5
        if held and task_name in RESUMES_HELD:
            return (yield from demo(op, params, rng, held=True))
        if touch is not None and not bool(np.all(touch)) and op.grip > 0.0:
            T = op.ee_pose_des()
            yield from grip(op, 0.0, 0.4)
            yield from move(op, K.pose(T[:3, :3], T[:3, 3] + [0.0, 0.0, LIFT_M]), 0.8)
        return (yield from demo(op, params, rng))

    return script


class TwinTakeoverOperator:
    """The per-tick hook (module doc). ts: the rollout's session; target: its PolicyTarget; eps: its
    TwinRollout; tk: its Takeover."""

    def __init__(self, ts, target, eps, tk):
        from hardware.arms.dynamics import ArmDynamics

        self.ts, self.target, self.eps, self.tk = ts, target, eps, tk
        # the pre-intervention window covers this operator's decision delay: it grabs after STALL_S of policy
        # control without progress, all of which it judged wrong (the rig's default 2 s is Sirius's, for a
        # person who intervenes as trouble starts); training weights the window as `pre`
        tk.cfg = dataclasses.replace(tk.cfg, pre_window_s=max(tk.cfg.pre_window_s, STALL_S))
        self.pair = ts.pairs[0]
        self.bank = eps.twin.bank(self.pair.leader.name)
        self.ee_site = mujoco.mj_name2id(eps.model, mujoco.mjtObj.mjOBJ_SITE, "ee")
        dyn = ArmDynamics(ts.session.rig.device(self.pair.follower.name).arm)
        lim = self.pair.follower.safety.limits
        self._op_args = (dyn.fk, dyn.jacobian, lim.q_min, lim.q_max, self.pair.map.backward, self.pair.dt_s)
        self.state, self.op, self.script = WATCH, None, None
        self._ep, self._k = None, 0
        self._progress, self._t_progress, self._t_hold, self._t_grab = 0.0, 0.0, np.nan, np.nan
        self._done_episode = False
        self.interventions = 0
        self._zero = np.zeros(self.pair.leader.n_joints + 1)

    def __call__(self, r) -> None:
        if r.pair != self.pair.cfg.name:
            return
        with sim_cpu.simulated():  # the simulated operator: not the app's CPU
            self._tick(r)

    def _tick(self, r) -> None:
        self._k += 1
        eps = self.eps
        if not (self.target.state == RUN and eps._state == RUN):
            if self.state != WATCH:
                self._let_go()
            return
        if eps._ep != self._ep:  # a new episode: watch from its start
            self._ep, self._done_episode = eps._ep, False
            self._progress, self._t_progress, self._t_hold = 0.0, r.t, np.nan
            self.state = WATCH
        if self.state == WATCH:
            self._watch(r)
        elif self.state == DRIVE:
            self._drive(r)
        else:
            self.bank.set_hand_torque(self._zero)

    def _watch(self, r) -> None:
        p = float(self.eps.tracker.progress)
        if p > self._progress:
            self._progress, self._t_progress = p, r.t
        held = self.pair.phase == HOLD
        self._t_hold = (self._t_hold if np.isfinite(self._t_hold) else r.t) if held else np.nan
        stalled = r.t - self._t_progress >= STALL_S
        faulted = held and r.t - self._t_hold >= HOLD_S
        if (stalled or faulted) and not self._done_episode:
            self._grab(r)
        else:
            self.bank.set_hand_torque(self._zero)

    def _grab(self, r) -> None:
        """Takes hold of the leader where the follower is, with the script of the task from here."""
        eps, mc = self.eps, self.pair.map.cfg
        self.op = op = Operator(*self._op_args, q_start=np.asarray(r.follower.q, float))
        g = r.follower.gripper_pos
        op.grip = float(np.clip((g - mc.gripper_offset) / mc.gripper_scale, 0.0, 1.0)) \
            if np.isfinite(g) and mc.gripper_scale else 0.0
        op.p = self._percept(r)
        self.script = finish_script(eps.task.name)(op, eps.params, np.random.default_rng(eps._ep_seed + 1))
        self.state, self._t_grab, self._done_episode = DRIVE, r.t, True
        eps.t_extended = r.t  # the episode's time limit restarts: the operator needs its time
        self.interventions += 1
        self._apply(r)

    def _drive(self, r) -> None:
        op = self.op
        self.tk.clutch = self.tk.driver == OPERATOR  # a person holding on pauses without handing back
        if self.tk.driver != OPERATOR and r.t - self._t_grab >= PEDAL_AFTER_S and not self.tk.pending:
            self.tk.press()  # the hand holds the leader but its push is small: the pedal confirms
            self._t_grab = np.inf
        if self._k % DECIDE_EVERY == 0:
            op.p = p = self._percept(r)
            try:
                next(self.script)
            except StopIteration:
                self._let_go()
                return
            op.decide(p, DECIDE_EVERY * self.pair.dt_s)
        self._apply(r)

    def _apply(self, r) -> None:
        q_l, qd_l = felt_joints(r.leader, self.bank)
        self.bank.set_hand_torque(self.op.torques(q_l, qd_l, r.leader.gripper_pos))

    def _let_go(self) -> None:
        self.bank.set_hand_torque(self._zero)
        self.tk.clutch = False  # the hand at rest now hands back
        self.state = LET_GO if self.target.state == RUN else WATCH

    def _percept(self, r) -> Percept:
        return percept(r, self.eps.data, self.ee_site, self.eps.observe())
