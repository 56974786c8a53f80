"""A policy rollout on the session layer: a trained policy drives the follower of a rig (twin or real) through
the same drivers, safety layer and NEXT estimator as teleop, and its episodes are judged and recorded like
demonstrations.

    result = run_rollout(RolloutOptions(rig="sim-piper", policy=Path("RUN"), task="peg-insert",
                                        episodes=20, seed=1000))
    result["success_rate"], result["stage_rates"], result["timing"]

What the user chooses (RolloutOptions) and what an app wires in (RolloutHooks: key queues, on_start, the
twin's scripted operator) are two things; session/rollout_plan.py resolves them into a RolloutPlan before any
device opens. Then three steps on the open rig: _build (session, target, episodes, hooks, recording), _run
(the loop, Ctrl-C, the arms put down) and _report (the RolloutResult).

Wiring: open_rig (lockstep on a twin by default, deterministic and as fast as the CPU goes; `realtime` for
timing, the loop thread stepping the twin as in the demo) -> RolloutSession, a TeleopSession whose pairs are
RolloutPairs (session/rollout_pair.py: same estimator and tables as teleop, follower from the policy's
schedule, leader at zero torque) -> PolicyRunner (policies/rollout: inline in lockstep, its own thread in
real time) -> episodes: TwinRollout on a twin task (the bookkeeping of `factr2 collect`, task_episodes.py:
objects placed per episode seed, stages, success, time limit) or MarkedRollout (the operator marks stages and
the outcome with keys). `record` writes one MCAP like demonstrations (outcome, stages, tau_ext, frames, the
follower command, the privileged object vector on twin tasks).
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from dataclasses import dataclass

import numpy as np

from factr2_teleop.session.pairs import TeleopOptions
from factr2_teleop.session.rollout_episodes import MarkedRollout, TwinRollout, episode_line
from factr2_teleop.session.rollout_pair import FRAME_MAX_AGE_S, RUN, PolicyTarget, RolloutPair, TargetArm
from factr2_teleop.session.rollout_plan import (
    K_EXEC_SHARE,
    NextNote,
    RolloutHooks,
    RolloutOptions,
    RolloutPlan,
    check_options,
    estimator_mode,
    plan_rollout,
    resolve_next,
    resolve_switches,
    rig_follower_arms,
)
from factr2_teleop.session.rollout_report import (
    RolloutResult,
    WireCheck,
    episode_summary,
    timing_summary,
    wire_summary,
)
from factr2_teleop.session.rollout_takeover import TakeoverPair, attach_takeover
from factr2_teleop.session.takeover_switch import Takeover, takeover_summary
from factr2_teleop.session.teleop import TeleopSession
from hardware.errors import UserError
from hardware.features import rig_arm_names, rig_features
from hardware.reasons import render
from policies.rollout.schedule import ENSEMBLE, RECEDING, ChunkSchedule

# what callers import from here (the options, the plan and the checks live in session/rollout_plan.py)
__all__ = ["K_EXEC_SHARE", "NextNote", "RolloutHooks", "RolloutOptions", "RolloutPlan", "RolloutResult",
           "RolloutSession", "check_options", "estimator_mode", "resolve_next", "resolve_switches",
           "rig_follower_arms", "run_rollout", "schedule_limits", "target_arms"]

FRAME_WAIT_S = 5.0  # s (wall): lockstep waits this long at most for a camera's frame of now
FRAME_POLL_S = 0.02  # s (wall): while waiting, look this often whether the renders answered without a frame
MARK_TIME_LIMIT_S = 60.0  # s: an operator-marked episode without --max-seconds ends unlabelled after this


class RolloutSession(TeleopSession):
    """A TeleopSession of RolloutPairs that also keeps every camera's latest frame (t [s], RGB) for the
    policy."""

    def __init__(self, session, opts: TeleopOptions, *, clock=None, pair_class=RolloutPair):
        self._latest: dict = {}
        self._cond = threading.Condition()
        super().__init__(session, opts, clock=clock, pair_class=pair_class)

    def _frame(self, camera: str, t: float, rgb) -> None:
        with self._cond:
            self._latest[camera] = (t, rgb)
            self._cond.notify_all()
        super()._frame(camera, t, rgb)

    def frames_at(self, now: float, cameras: list[str], max_age_s: float, wait: bool) -> dict | None:
        """{camera: RGB} when every camera's latest frame is at most max_age_s [s] old at `now`, else None.
        wait (lockstep): block up to FRAME_WAIT_S of wall time for the renders to catch up -- simulated time
        stands still meanwhile, so the policy sees the frame of now, as in real time, and runs stay
        deterministic (a twin camera renders a snapshot taken on the stepping thread, QUEUE_FRAMES behind)."""
        end = time.monotonic() + FRAME_WAIT_S
        with self._cond:
            while True:
                got = {c: self._latest.get(c, (-np.inf, None)) for c in cameras}
                if all(now - t <= max_age_s for t, _ in got.values()):
                    return {c: rgb for c, (_, rgb) in got.items()}
                left = end - time.monotonic()
                if not wait or left <= 0 or self._renders_done(cameras, now - max_age_s):
                    return None  # (renders caught up and no fresh frame: a frozen or gone camera)
                self._cond.wait(min(left, FRAME_POLL_S))

    def _renders_done(self, cameras: list[str], t: float) -> bool:
        """Every camera's render thread has answered (frame or failure) the snapshot of t [s] or later."""
        stream = self.cameras
        done = getattr(stream, "answered_t", None)
        return done is not None and all(done.get(c, -np.inf) >= t for c in cameras)


# -- the whole rollout ----------------------------------------------------------------------------------
def run_rollout(opts: RolloutOptions, hooks: RolloutHooks | None = None) -> RolloutResult:
    """Roll the policy out (blocking); its RolloutResult (see the module doc and docs/rollout.md). hooks: what
    an app wires in (RolloutHooks; none by default). Ctrl-C holds every follower, leaves every leader at zero
    torque and returns what was done (interrupted)."""
    from hardware.threads import limit_threads
    from policies.rollout.runner import PolicyRunner

    hooks = hooks if hooks is not None else RolloutHooks()
    runner = PolicyRunner(opts.policy, seed=opts.seed, ema=opts.ema, force_input=opts.force_input)
    rig, task = check_options(opts, runner)
    plan = plan_rollout(opts, hooks, runner, rig)
    # the loop keeps a core of its own; a chunk's work is small (docs/rollout.md)
    with limit_threads(1, torch=True):
        return _rollout(opts, hooks, runner, rig, task, plan)


def target_arms(ts, runner, layout: dict, task) -> list[TargetArm]:
    """One TargetArm per pair of the session, in pair order: its recorded arm name (hardware.features),
    its columns of the action (the runner's layout), its gripper range, and on a twin task the open
    gripper it homes to."""
    arms = []
    for pair, (_p, arm) in zip(ts.pairs, rig_arm_names(ts.session.rig)):
        q, grip = layout[arm]
        mc = pair.map.cfg
        arms.append(TargetArm(pair, arm, q, grip, (mc.gripper_min, mc.gripper_max),
                              pair.map.gripper_forward(0.0) if task is not None else None))
    return arms


def schedule_limits(arms: list[TargetArm], width: int) -> tuple[np.ndarray, np.ndarray]:
    """Joint limits [rad] over the whole action vector: each arm's on its joint columns, none (+-inf) on the
    gripper columns (clamped, never judged): a chunk beyond them is refused (ChunkSchedule)."""
    lo, hi = np.full(width, -np.inf), np.full(width, np.inf)
    for a in arms:
        lim = a.pair.follower.safety.limits
        lo[a.q], hi[a.q] = lim.q_min, lim.q_max
    return lo, hi


def _episodes(opts: RolloutOptions, hooks: RolloutHooks, ts, task, target: PolicyTarget, stages: tuple):
    def said(res):
        if opts.progress:
            print(episode_line(res, stages), flush=True)

    if task is not None:
        eps = TwinRollout(ts, task, opts.episodes, opts.seed, target, opts.max_seconds or task.episode_s,
                          on_episode=said)
        return eps
    return MarkedRollout(ts, target, opts.episodes, stages, opts.max_seconds or MARK_TIME_LIMIT_S,
                         hooks.marks, on_episode=said)


@dataclass
class Built:
    """A rollout wired on an open rig, before its loop runs (_build), and what its run leaves (_run)."""

    ts: RolloutSession
    clock: object  # the rig's clock, or the TwinDrivenClock the loop's thread steps in real time
    arms: list[TargetArm]
    sched: ChunkSchedule
    target: PolicyTarget
    eps: TwinRollout | MarkedRollout
    tk: Takeover | None
    stages: tuple
    periods: list[float]  # s: the loop's periods while the policy runs
    wires: list[WireCheck]
    rec_path: str | None = None
    rec_status: object = None  # the recording's RecorderStatus once closed
    interrupted: bool = False


def _rollout(opts: RolloutOptions, hooks: RolloutHooks, runner, rig, task,
             plan: RolloutPlan) -> RolloutResult:
    from hardware.connect import open_rig

    t_wall = time.perf_counter()
    # a twin's Dynamixel leader in process (the sdk's packet layer unchanged, no pty and no emulator thread
    # to hand the GIL to), as the demo does: in real time a pty thread costs the loop its p99 period
    transport = "inprocess" if rig.simulated else None
    with open_rig(rig, clock="realtime" if plan.realtime else "lockstep", seed=opts.seed,
                  dynamixel_transport=transport, faults=opts.faults) as s:
        b = _build(s, opts, hooks, runner, rig, task, plan)
        _run(s, b, opts, hooks, runner, rig, plan)
        ends = _ends(s, b.ts)
    return _report(opts, runner, rig, task, plan, b, ends, t_wall)


def _build(s, opts: RolloutOptions, hooks: RolloutHooks, runner, rig, task, plan: RolloutPlan) -> Built:
    """The session of RolloutPairs on the open rig `s`, the policy's target and schedule, the episodes, the
    takeover, the per-tick hooks, the wire checks and the recording, in the order the loop sees them."""
    from hardware.sim.twin_driven_clock import TwinDrivenClock

    clock = s.clock
    if plan.realtime and s.twin is not None:  # the loop's thread steps the twin (as the demo does)
        s.twin.stop_realtime()
        clock = TwinDrivenClock(s.twin)
    ts = RolloutSession(s, TeleopOptions(mode=plan.mode, checkpoint=str(plan.next_path)
                                         if plan.next_path else None), clock=clock,
                        pair_class=TakeoverPair if plan.takeover else RolloutPair)
    features = rig_features(rig)
    arms = target_arms(ts, runner, runner.check_rig(features, rig_follower_arms(rig)), task)
    if plan.lean:  # the passive leaders: nothing records or shows them, the followers' law ignores them
        for pair in ts.pairs:
            pair.rest_leader()
            s.twin.set_idle(pair.leader.name)
    q_min, q_max = schedule_limits(arms, runner.cfg.action_dim)
    sched = ChunkSchedule(mode=plan.schedule, dt=runner.dt, q_min=q_min, q_max=q_max, m=opts.ensemble_m,
                          k_exec=plan.k_exec)
    fps = min((c.fps for c in rig.cameras if c.name in runner.cameras), default=30.0)
    max_age = FRAME_MAX_AGE_S if plan.realtime else 1.0 / fps + 1e-6  # lockstep: the frame due last

    def frames(now):
        return ts.frames_at(now, runner.cameras, max_age, wait=not plan.realtime)

    target = PolicyTarget(arms, runner, sched, features, frames=frames)
    for i, pair in enumerate(ts.pairs):
        pair.follow(target.for_pair(i))
    stages = tuple(task.stages) if task is not None else ()
    eps = _episodes(opts, hooks, ts, task, target, stages)
    tk = attach_takeover(ts, target, hooks.takeover_keys) if plan.takeover else None
    if tk is not None and hooks.operator is not None:
        ts.hooks.append(hooks.operator(ts, target, eps, tk))
    first = ts.pairs[0].cfg.name  # per-tick hooks see every pair's record: the episode owner ticks once
    periods: list[float] = []
    ts.hooks.append(lambda r: eps.on_tick(r) if r.pair == first else None)
    ts.hooks.append(lambda r: periods.append(r.loop_period_s)
                    if r.pair == first and target.state == RUN else None)
    wires = []
    for pair in ts.pairs:
        wires.append(WireCheck(pair.follower.safety.limits))
        pair.follower.add_command_observer(wires[-1])
        pair.leader.add_command_observer(wires[-1].leader)
    b = Built(ts, clock, arms, sched, target, eps, tk, stages, periods, wires)
    if opts.record is not None:
        tname = task.name if task else ""
        rec = ts.record(opts.record, stem=f"rollout-{tname or rig.name}", task=tname,
                        cameras=opts.record_cameras,
                        extra_meta={"simulated": str(s.twin is not None).lower(), "operator": "policy",
                                    "policy": str(runner.path), "rollout_seed": opts.seed})
        b.rec_path = str(rec.path)
        if tk is not None:
            tk.recording = rec
    return b


def _run(s, b: Built, opts: RolloutOptions, hooks: RolloutHooks, runner, rig, plan: RolloutPlan) -> None:
    """The policy started, the cameras it looks through, the loop run to the last episode (or Ctrl-C:
    b.interrupted); the arms put down and the recording closed however it ended."""
    from hardware.sim.twin_driven_clock import TwinDrivenClock

    ts = b.ts
    runner.start(plan.threaded)
    try:
        # frames only when the policy looks (else the recording starts the cameras with its first episode)
        problems = ts.start_cameras() if runner.cameras else []
        if problems:
            raise UserError(f"camera problem: {problems[0]}", where=str(rig.path),
                            fix="check the rig's cameras")
        if opts.progress:
            head = f"{runner.describe()}\n" + "\n".join(ts.describe()) + f", schedule {plan.schedule}, "
            print(head + ("real time" if plan.realtime else "lockstep")
                  + (f"\nnote: {plan.note}" if plan.note else ""), flush=True)
        if hooks.on_start is not None:
            hooks.on_start(ts, b.target, b.eps)
        if isinstance(b.clock, TwinDrivenClock):
            b.clock.start()
        ts.loop.run()
    except KeyboardInterrupt:
        b.interrupted = True
    finally:
        runner.stop()
        # the arms put down at once (a leader at zero torque, a follower held or disabled as its driver
        # does), before the recording's slower close: else their own timeouts fall back meanwhile
        s.disconnect_arms()
        b.rec_status = ts.close_recording("rollout interrupted" if b.interrupted else "")


def _ends(s, ts) -> dict:
    """What the rig and the session hold at the end, read before the rig closes."""
    return {"holds": sum((p.holds for p in ts.pairs), Counter()),
            "clipped": sum(int(p.follower.safety.clipped) for p in ts.pairs),
            "feedback": ts.pairs[0].mode,
            "messages": list(ts.loop.snapshot().messages),
            "faults": list(s.twin.faults.log) if s.twin is not None and s.twin.faults is not None else []}


def _report(opts: RolloutOptions, runner, rig, task, plan: RolloutPlan, b: Built, ends: dict,
            t_wall: float) -> RolloutResult:
    """The RolloutResult: the episodes and the rates (as the recording's file holds them), the timing and
    the wire's checks."""
    eps = episode_summary(b.eps.results, b.stages, b.rec_path, b.rec_status)
    as_recorded = eps.pop("as_recorded")
    out = RolloutResult(
        simulated=rig.simulated, rig=rig.name, task=task.name if task else None, policy=str(runner.path),
        policy_kind=runner.policy, method=runner.meta.get("method"), schedule=plan.schedule,
        k_exec=plan.k_exec if plan.schedule == RECEDING else None,
        ensemble_m=opts.ensemble_m if plan.schedule == ENSEMBLE else None, seed=opts.seed,
        feedback_mode=ends["feedback"], force_input=opts.force_input,
        next=str(plan.next_path) if plan.next_path else None, note=render(plan.note),
        lean=plan.lean, interrupted=b.interrupted, wall_s=time.perf_counter() - t_wall, **eps,
        recording=b.rec_path, arms=[a.arm for a in b.arms], messages=ends["messages"], faults=ends["faults"],
        takeover=takeover_summary(b.tk, b.ts.pairs, as_recorded) if b.tk is not None else {})
    wire = wire_summary(b.wires)
    out.timing = timing_summary(b.periods, runner.latencies_s, b.target.ages_s, plan.realtime, b.ts.rate_hz)
    out.timing.update({"commands_sent": wire["commands_sent"],
                       "command_violations": wire["command_violations"],
                       "refused_nonfinite": b.sched.nonfinite,
                       "refused_outside_limits": b.sched.outside_limits,
                       "holds": dict(ends["holds"]), "targets_clamped": b.target.clamped,
                       "safety_clipped": ends["clipped"],
                       "end_follower_held": wire["end_follower_held"],
                       "end_leader_tau_max_nm": wire["end_leader_tau_max_nm"],
                       "hold_times_s": wire["hold_times_s"]})  # when a follower went on hold (loop clock)
    return out
