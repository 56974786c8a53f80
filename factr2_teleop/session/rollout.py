"""A policy rollout on the session layer: a trained policy drives the follower of a rig (twin or real) through
the same drivers, safety layer and NEXT estimator as teleop, and its episodes are judged and recorded like
demonstrations.

    result = run_rollout(RolloutOptions(rig="sim-piper", policy=Path("RUN"), task="peg-insert",
                                        episodes=20, seed=1000))
    result["success_rate"], result["stage_rates"], result["timing"]

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

import queue
import threading
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from enum import Enum
from pathlib import Path

import numpy as np

from calibration.next.ident import json_path, parse_ids
from factr2_teleop.session.pairs import TeleopOptions
from factr2_teleop.session.rollout_episodes import MarkedRollout, TwinRollout, episode_line
from factr2_teleop.session.rollout_pair import FRAME_MAX_AGE_S, RUN, PolicyTarget, RolloutPair, TargetArm
from factr2_teleop.session.rollout_report import RolloutResult, WireCheck, timing_summary, wire_summary
from factr2_teleop.session.rollout_takeover import TakeoverPair, attach_takeover, takeover_summary
from factr2_teleop.session.teleop import TeleopSession
from hardware.errors import UserError
from hardware.features import rig_arm_names, rig_features
from hardware.reasons import Reason, messages, render
from policies.rollout.schedule import ACT_ENSEMBLE_M, ENSEMBLE, RECEDING, ChunkSchedule

FRAME_WAIT_S = 5.0  # s (wall): lockstep waits this long at most for a camera's frame of now
FRAME_POLL_S = 0.02  # s (wall): while waiting, look this often whether the renders answered without a frame
K_EXEC_SHARE = 3  # flow: by default a third of each chunk is executed (10 of 30 steps, 1/3 s at 30 Hz)
EPISODE_KEYS = ("index", "seed", "outcome", "progress", "stages", "duration_s")  # of each EpisodeResult
MARK_TIME_LIMIT_S = 60.0  # s: an operator-marked episode without --max-seconds ends unlabelled after this


@dataclass
class RolloutOptions:
    """rig: rig name or file; policy: RUN folder or step-*.json; task: a twin task (None: the operator marks
    episodes); episodes: how many; seed: episode k uses task_episodes.episode_seed(seed, k) like collection;
    record: folder for the MCAP; max_seconds: episode time limit [s] (default the task's); next: a NEXT
    checkpoint other than the policy's (said); realtime: wall-clock loop on a twin (timing); progress: print
    a line per episode. mode: estimator when the policy names no NEXT checkpoint (default the rig's);
    schedule: "ensemble" / "receding" (default ensemble, ACT and flow); ensemble_m; k_exec; threaded:
    inference on its own thread (default: in real time only); marks: a queue.SimpleQueue of keys (s/y/n/q)
    for operator-marked episodes; on_start: callable(session, target, episodes) once everything is built,
    before the loop runs (a UI's live view: add a tick hook, stop the loop). lean: skip what only a recording
    or a watcher reads -- the passive leader's simulation and service, and the estimator when the policy
    observes no force (None: on for a lockstep twin without record and on_start; the follower's commands
    are the same either way, docs/rollout.md "Rollout CPU"). takeover: the leader follows and the operator
    can take over (session/rollout_takeover.py; None: on in real time and in the app, off for a lockstep
    twin, where no hand acts unless `operator` is given); operator: callable(ts, target, episodes,
    takeover) -> a per-tick hook, the twin's scripted operator (tasks/takeover_operator.py); takeover_keys:
    the queue the takeover key (or pedal) is put into."""

    rig: str
    policy: Path
    task: str | None = None
    episodes: int = 1
    seed: int = 0
    record: Path | None = None
    record_cameras: bool = True  # the recording takes the rig's cameras' frames (`--no-cameras`: not)
    max_seconds: float | None = None
    next: Path | None = None
    realtime: bool = False
    progress: bool = True
    mode: str | None = None
    schedule: str | None = None
    ensemble_m: float = ACT_ENSEMBLE_M
    k_exec: int | None = None
    threaded: bool | None = None
    marks: object = None
    on_start: object = None
    lean: bool | None = None
    force: bool = False  # roll out on another task than the demonstrations' (session/task_check.py)
    ema: bool = True  # the checkpoint's moving-average weights where it has them (else the trained ones)
    takeover: bool | None = None
    operator: object = None
    takeover_keys: object = field(default_factory=queue.SimpleQueue)  # TOGGLE_KEY presses (any thread)
    faults: list | None = None  # hardware.sim.faults.FaultSpec the twin plays (None: the rig's [twin] faults)
    force_input: str = "live"  # the policy's force input: live, or ablated (zero, shuffle; policies/rollout)


# -- the NEXT checkpoint the policy was trained with -----------------------------------------------------
class NextNote(Enum):
    """What resolve_next has to say (hardware.reasons)."""

    # --next names another checkpoint than the one the policy was trained with (detail: path, ident)
    NOT_TRAINED_WITH = "not the trained NEXT"


messages({NextNote.NOT_TRAINED_WITH: ("NEXT {path} is NOT the checkpoint the policy was trained with "
                                      "({ident}): used as --next asks")})


def resolve_next(meta: dict, explicit: Path | None) -> tuple[Path | None, Reason | None]:
    """(NEXT checkpoint to run or None, a note to show or None). The policy's NEXT is meta["next_checkpoint"]
    (calibration.next.ident). UserError when the policy's is not here and no --next was given."""
    ids = parse_ids(meta.get("next_checkpoint"))
    if len(ids) > 1:
        raise UserError("policy trained on several arms' NEXT checkpoints; rollout drives one arm",
                        where=str(meta.get("_path")), fix="train on single-arm recordings")
    ident = ids[0] if ids else None
    if explicit is not None:
        p = json_path(explicit)
        if not p.is_file():
            raise UserError("NEXT checkpoint not found", where=str(explicit), fix="pass --next DIR/next.json")
        if ident is not None and not ident.matches(p):
            return p, Reason.of(NextNote.NOT_TRAINED_WITH, path=p, ident=ident)
        return p, None
    if ident is None:
        return None, None
    here = ident.located()
    if here is not None:
        return here, None
    raise UserError(f"the policy was trained with NEXT {ident}, which is not here (or has changed)",
                    where="--policy",
                    fix="pass --next CKPT to run another NEXT checkpoint (the summary says so)")


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
def check_options(opts: RolloutOptions, runner):
    """Everything refusable before a device is opened (UserError, one line); returns (rig, task): the rig
    as the rollout opens it (a twin task adds its scene and cameras) and the task or None. The terminal app
    checks a run against the rig with it too."""
    from factr2_teleop.session.task_check import check_task
    from factr2_teleop.session.task_episodes import task_rig
    from hardware.rigs.rig import load_rig
    from hardware.sim.tasks import get_task

    if opts.episodes < 1:
        raise UserError(f"--episodes {opts.episodes} must be at least 1", where="--episodes", fix="e.g. 20")
    rig = load_rig(opts.rig)
    task = get_task(opts.task) if opts.task else None
    check_task(runner.meta, opts.task, opts.force)  # another task than the demonstrations': forced only
    if task is not None:
        rig = task_rig(rig, task)  # ConfigError for a real rig or an arm that cannot hold the task
    runner.check_rig(rig_features(rig), rig_follower_arms(rig))
    have = {c.name for c in rig.cameras}
    missing = [c for c in runner.cameras if c not in have]
    if missing:
        raise UserError(f"the policy needs camera(s) {', '.join(missing)}; rig {rig.name} has "
                        f"{', '.join(sorted(have)) or 'none'}", where=str(rig.path),
                        fix="add them to the rig (the names used in training), or pass --task on a twin")
    if runner.uses_objects and task is None:
        raise UserError("the policy observes twin task objects (privileged or perceived): it runs only on a "
                        "twin task",
                        where="--policy", fix="pass --task T on a sim-* rig, or train on images")
    if opts.schedule not in (None, ENSEMBLE, RECEDING):
        raise UserError(f"unknown schedule {opts.schedule!r}", where="--schedule", fix="ensemble or receding")
    if opts.k_exec is not None and not 1 <= opts.k_exec <= runner.cfg.chunk:
        raise UserError(f"{opts.k_exec} steps outside 1..{runner.cfg.chunk} (the policy's chunk)",
                        where="--k-exec", fix=f"e.g. {max(1, runner.cfg.chunk // K_EXEC_SHARE)}")
    return rig, task


def estimator_mode(next_path, asked: str | None, trained: str, uses_force: bool) -> str | None:
    """The feedback estimator a rollout runs: NEXT when the policy names its checkpoint; the estimator a
    policy's recorded tau_ext came from (meta "tau_ext_estimator", e.g. dob) when it reads force, so that it
    is fed what it was trained on; else --mode (None: the rig's). UserError when --mode asks for another."""
    if next_path is not None:
        return "next"
    if uses_force and trained and "," not in trained and trained != "next":
        if asked not in (None, trained):
            raise UserError(f"the policy was trained on the {trained} estimator's tau_ext; --mode {asked} "
                            "would feed it another estimate", where="--mode",
                            fix=f"leave --mode out or pass {trained}")
        return trained
    return asked


def run_rollout(opts: RolloutOptions) -> RolloutResult:
    """Roll the policy out (blocking); its RolloutResult (see the module doc and docs/rollout.md). Ctrl-C
    holds every follower, leaves every leader at zero torque and returns what was done (interrupted)."""
    from hardware.threads import limit_threads
    from policies.rollout.runner import PolicyRunner

    runner = PolicyRunner(opts.policy, seed=opts.seed, ema=opts.ema, force_input=opts.force_input)
    rig, task = check_options(opts, runner)
    next_path, note = resolve_next(runner.meta, opts.next)
    if next_path is not None and opts.mode not in (None, "next"):
        raise UserError(f"the policy was trained on NEXT's tau_ext; --mode {opts.mode} would feed it another "
                        "estimate", where="--mode", fix="leave --mode out")
    realtime = opts.realtime or not rig.simulated
    takeover = opts.takeover if opts.takeover is not None else (
        realtime or opts.operator is not None)
    lean = not realtime and not takeover and (opts.lean if opts.lean is not None else
                             opts.record is None and opts.on_start is None)
    mode = estimator_mode(next_path, opts.mode, str(runner.meta.get("tau_ext_estimator", "")),
                          bool(runner.force_names))
    if lean and not runner.force_names:
        mode = "none"  # the estimate is an input of the policy and a recorded topic only: nobody reads it
    plan = RolloutPlan(next_path=next_path, note=note, mode=mode, lean=lean, realtime=realtime,
                       threaded=opts.threaded if opts.threaded is not None else realtime,
                       schedule=opts.schedule or ENSEMBLE,  # flow too: docs/first.md "Chunk execution"
                       k_exec=opts.k_exec or max(1, runner.cfg.chunk // K_EXEC_SHARE), takeover=takeover)
    # the loop keeps a core of its own; a chunk's work is small (docs/rollout.md)
    with limit_threads(1, torch=True):
        return _rollout(opts, runner, rig, task, plan)


@dataclass(frozen=True)
class RolloutPlan:
    """What run_rollout decided before any device opens: the NEXT checkpoint (and the note said about it),
    the estimator mode, lean, real time, inference threaded, the chunk schedule and its k_exec."""

    next_path: Path | None
    note: Reason | None  # a NextNote reason
    mode: str | None
    lean: bool
    realtime: bool
    threaded: bool
    schedule: str
    k_exec: int
    takeover: bool = False  # the leader follows and the operator may take over


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


def _episodes(opts: RolloutOptions, ts, task, target: PolicyTarget, stages: tuple):
    def said(res):
        if opts.progress:
            print(episode_line(res, stages), flush=True)

    if task is not None:
        eps = TwinRollout(ts, task, opts.episodes, opts.seed, target, opts.max_seconds or task.episode_s,
                          on_episode=said)
        return eps
    return MarkedRollout(ts, target, opts.episodes, stages, opts.max_seconds or MARK_TIME_LIMIT_S, opts.marks,
                         on_episode=said)


def _rollout(opts: RolloutOptions, runner, rig, task, plan: RolloutPlan) -> RolloutResult:
    from hardware.connect import open_rig
    from hardware.sim.twin import TwinDrivenClock

    t_wall = time.perf_counter()
    interrupted, rec_path = False, None
    # a twin's Dynamixel leader in process (the sdk's packet layer unchanged, no pty and no emulator thread
    # to hand the GIL to), as the demo does: in real time a pty thread costs the loop its p99 period
    transport = "inprocess" if rig.simulated else None
    with open_rig(rig, clock="realtime" if plan.realtime else "lockstep", seed=opts.seed,
                  dynamixel_transport=transport, faults=opts.faults) as s:
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
        eps = _episodes(opts, ts, task, target, stages)
        tk = attach_takeover(ts, target, opts.takeover_keys) if plan.takeover else None
        if tk is not None and opts.operator is not None:
            ts.hooks.append(opts.operator(ts, target, eps, tk))
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
        if opts.record is not None:
            tname = task.name if task else ""
            rec = ts.record(opts.record, stem=f"rollout-{tname or rig.name}", task=tname,
                            cameras=opts.record_cameras,
                            extra_meta={"simulated": str(s.twin is not None).lower(), "operator": "policy",
                                        "policy": str(runner.path), "rollout_seed": opts.seed})
            rec_path = str(rec.path)
            if tk is not None:
                tk.recording = rec
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
            if opts.on_start is not None:
                opts.on_start(ts, target, eps)
            if isinstance(clock, TwinDrivenClock):
                clock.start()
            ts.loop.run()
        except KeyboardInterrupt:
            interrupted = True
        finally:
            runner.stop()
            # the arms put down at once (a leader at zero torque, a follower held or disabled as its driver
            # does), before the recording's slower close: else their own timeouts fall back meanwhile
            s.disconnect_arms()
            ts.close_recording("rollout interrupted" if interrupted else "")
        holds = sum((p.holds for p in ts.pairs), Counter())
        clipped = sum(int(p.follower.safety.clipped) for p in ts.pairs)
        feedback = ts.pairs[0].mode
        messages = list(ts.loop.snapshot().messages)
        faults = list(s.twin.faults.log) if s.twin is not None and s.twin.faults is not None else []
    res = eps.results
    out = RolloutResult(
        simulated=rig.simulated, rig=rig.name, task=task.name if task else None, policy=str(runner.path),
        policy_kind=runner.policy, method=runner.meta.get("method"), schedule=plan.schedule,
        k_exec=plan.k_exec if plan.schedule == RECEDING else None,
        ensemble_m=opts.ensemble_m if plan.schedule == ENSEMBLE else None, seed=opts.seed,
        feedback_mode=feedback, force_input=opts.force_input,
        next=str(plan.next_path) if plan.next_path else None, note=render(plan.note),
        lean=plan.lean, interrupted=interrupted, wall_s=time.perf_counter() - t_wall,
        episodes=[{k: v for k, v in asdict(r).items() if k in EPISODE_KEYS} for r in res],
        success_rate=float(np.mean([r.outcome == "success" for r in res])) if res else 0.0,
        mean_progress=float(np.mean([r.progress for r in res])) if res else 0.0,
        stage_rates={s: float(np.mean([r.stages.get(s) is not None for r in res])) if res else 0.0
                     for s in stages},
        recording=rec_path, arms=[a.arm for a in arms], messages=messages, faults=faults,
        takeover=takeover_summary(tk, ts.pairs, res) if tk is not None else {})
    wire = wire_summary(wires)
    out.timing = timing_summary(periods, runner.latencies_s, target.ages_s, plan.realtime, ts.rate_hz)
    out.timing.update({"commands_sent": wire["commands_sent"],
                       "command_violations": wire["command_violations"],
                       "refused_nonfinite": sched.nonfinite, "refused_outside_limits": sched.outside_limits,
                       "holds": dict(holds), "targets_clamped": target.clamped, "safety_clipped": clipped,
                       "end_follower_held": wire["end_follower_held"],
                       "end_leader_tau_max_nm": wire["end_leader_tau_max_nm"],
                       "hold_times_s": wire["hold_times_s"]})  # when a follower went on hold (loop clock)
    return out


def rig_follower_arms(rig) -> dict[str, tuple[str, list[str]]]:
    """The rig's follower arms by recorded name: (arm model, joint names): what a policy is checked
    against."""
    from hardware.arms import load_arm

    out = {}
    for (_lead, fol), (_p, arm) in zip(rig.pairs, rig_arm_names(rig)):
        spec = rig.device(fol)
        out[arm] = (spec.arm, list(load_arm(spec.arm).joint_names))
    return out
