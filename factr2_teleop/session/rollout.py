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
real time) -> episodes: TwinRollout on a twin task (the bookkeeping of `factr2 collect`, tasks/collect.py:
objects placed per episode seed, stages, success, time limit) or MarkedRollout (the operator marks stages and
the outcome with keys). `record` writes one MCAP like demonstrations (outcome, stages, tau_ext, frames, the
follower command, the privileged object vector on twin tasks).
"""

from __future__ import annotations

import threading
import time
from dataclasses import asdict, dataclass
from enum import Enum
from pathlib import Path

import numpy as np

from calibration.next.ident import json_path, parse_ids
from factr2_teleop.session.pairs import TeleopOptions
from factr2_teleop.session.rollout_episodes import MarkedRollout, TwinRollout, episode_line
from factr2_teleop.session.rollout_pair import FRAME_MAX_AGE_S, RUN, PolicyTarget, RolloutPair
from factr2_teleop.session.teleop import TeleopSession
from hardware.errors import UserError
from hardware.reasons import Reason, messages, render
from policies.rollout.schedule import ACT_ENSEMBLE_M, ENSEMBLE, RECEDING, ChunkSchedule

FRAME_WAIT_S = 5.0  # s (wall): lockstep waits this long at most for a camera's frame of now
K_EXEC_SHARE = 3  # flow: by default a third of each chunk is executed (10 of 30 steps, 1/3 s at 30 Hz)
MARK_TIME_LIMIT_S = 60.0  # s: an operator-marked episode without --max-seconds ends unlabelled after this


@dataclass
class RolloutOptions:
    """rig: rig name or file; policy: RUN folder or step-*.json; task: a twin task (None: the operator marks
    episodes); episodes: how many; seed: episode k uses tasks.collect.episode_seed(seed, k) like collection;
    record: folder for the MCAP; max_seconds: episode time limit [s] (default the task's); next: a NEXT
    checkpoint other than the policy's (said); realtime: wall-clock loop on a twin (timing); progress: print
    a line per episode. mode: estimator when the policy names no NEXT checkpoint (default the rig's);
    schedule: "ensemble" / "receding" (default ACT ensemble, flow receding); ensemble_m; k_exec; threaded:
    inference on its own thread (default: in real time only); marks: a queue.SimpleQueue of keys (s/y/n/q)
    for operator-marked episodes; on_start: callable(session, target, episodes) once everything is built,
    before the loop runs (a UI's live view: add a tick hook, stop the loop). lean: skip what only a recording
    or a watcher reads -- the passive leader's simulation and service, and the estimator when the policy
    observes no force (None: on for a lockstep twin without record and on_start; the follower's commands
    are the same either way, docs/rollout.md "Rollout CPU")."""

    rig: str
    policy: Path
    task: str | None = None
    episodes: int = 1
    seed: int = 0
    record: Path | None = None
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

    def __init__(self, session, opts: TeleopOptions, *, clock=None):
        self._latest: dict = {}
        self._cond = threading.Condition()
        super().__init__(session, opts, clock=clock, pair_class=RolloutPair)

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
                if not wait or left <= 0:
                    return None
                self._cond.wait(left)


# -- the whole rollout ----------------------------------------------------------------------------------
def check_options(opts: RolloutOptions, runner):
    """Everything refusable before a device is opened (UserError, one line); returns (rig, task): the rig
    as the rollout opens it (a twin task adds its scene and cameras) and the task or None. The terminal app
    checks a run against the rig with it too."""
    from factr2_teleop.session.task_check import check_task
    from factr2_teleop.tasks.collect import task_rig
    from hardware.arms import load_arm
    from hardware.rigs.rig import load_rig
    from hardware.sim.tasks import get_task

    if opts.episodes < 1:
        raise UserError(f"--episodes {opts.episodes} must be at least 1", where="--episodes", fix="e.g. 20")
    rig = load_rig(opts.rig)
    task = get_task(opts.task) if opts.task else None
    check_task(runner.meta, opts.task, opts.force)  # another task than the demonstrations': forced only
    if task is not None:
        rig = task_rig(rig, task)  # ConfigError for a real rig or an arm that cannot hold the task
    if len(rig.pairs) != 1:
        raise UserError(f"rig {rig.name} has {len(rig.pairs)} arm pairs; rollout drives one",
                        where=str(rig.path), fix="use a single-arm rig")
    fspec = rig.device(rig.pairs[0][1])
    runner.check_arm(fspec.arm, list(load_arm(fspec.arm).joint_names))
    have = {c.name for c in rig.cameras}
    missing = [c for c in runner.cameras if c not in have]
    if missing:
        raise UserError(f"the policy needs camera(s) {', '.join(missing)}; rig {rig.name} has "
                        f"{', '.join(sorted(have)) or 'none'}", where=str(rig.path),
                        fix="add them to the rig (the names used in training), or pass --task on a twin")
    if runner.uses_objects and task is None:
        raise UserError("the policy observes the PRIVILEGED twin object state: it runs only on a twin task",
                        where="--policy", fix="pass --task T on a sim-* rig, or train on images")
    if opts.schedule not in (None, ENSEMBLE, RECEDING):
        raise UserError(f"unknown schedule {opts.schedule!r}", where="--schedule", fix="ensemble or receding")
    if opts.k_exec is not None and not 1 <= opts.k_exec <= runner.cfg.chunk:
        raise UserError(f"{opts.k_exec} steps outside 1..{runner.cfg.chunk} (the policy's chunk)",
                        where="--k-exec", fix=f"e.g. {max(1, runner.cfg.chunk // K_EXEC_SHARE)}")
    return rig, task


class WireCheck:
    """Command observers at the wire (after the safety layer): follower commands sent, those with a joint
    target outside the limits or not finite (an independent check of the layer: should stay 0), the times
    the follower went on hold [s], and the last command of each arm (Ctrl-C must end on a follower hold and
    a zero leader torque)."""

    def __init__(self, limits):
        self.q_min, self.q_max = np.asarray(limits.q_min), np.asarray(limits.q_max)
        self._lo, self._hi = self.q_min - 1e-9, self.q_max + 1e-9
        self.sent = self.violations = 0
        self.hold_times: list[float] = []  # t_sent of each hold entered
        self.last_hold = False
        self.leader_tau = None

    def __call__(self, t_issued, t_sent, safe) -> None:
        q = np.asarray(safe.q, dtype=float)
        self.sent += 1
        if not ((q >= self._lo) & (q <= self._hi)).all():  # NaN fails both comparisons, +-inf one of them
            self.violations += 1
        if safe.hold and not self.last_hold:
            self.hold_times.append(float(t_sent))
        self.last_hold = bool(safe.hold)

    def leader(self, t_issued, t_sent, safe) -> None:
        self.leader_tau = np.asarray(safe.tau, dtype=float)


def _pct(x, p: float) -> float:
    return float(np.percentile(x, p)) if len(x) else float("nan")


def timing_summary(periods_s, latencies_s, ages_s, realtime: bool, target_hz: float) -> dict:
    """Loop rate [Hz] and period p99 / max [ms] over the policy's run ticks, chunk latency and action age
    mean / p99 [ms]. In lockstep, periods and ages are simulated time (latency is wall time)."""
    p = np.asarray([x for x in periods_s if np.isfinite(x)])
    lat, age = np.asarray(latencies_s) * 1e3, np.asarray(ages_s) * 1e3
    return {"clock": "real time" if realtime else "lockstep (simulated time; latency is wall time)",
            "loop_target_hz": target_hz, "loop_rate_hz": float(1.0 / p.mean()) if len(p) else float("nan"),
            "period_p99_ms": _pct(p * 1e3, 99),
            "period_max_ms": float(p.max() * 1e3) if len(p) else float("nan"),
            "overruns": int(np.sum(p > 1.5 / target_hz)), "ticks": int(len(p)),
            "chunks": int(len(lat)), "chunk_latency_mean_ms": float(lat.mean()) if len(lat) else float("nan"),
            "chunk_latency_p99_ms": _pct(lat, 99),
            "action_age_mean_ms": float(age.mean()) if len(age) else float("nan"),
            "action_age_p99_ms": _pct(age, 99)}


def run_rollout(opts: RolloutOptions) -> dict:
    """Roll the policy out (blocking); the summary dict (see the module doc and docs/rollout.md). Ctrl-C
    holds the follower, leaves the leader at zero torque and returns what was done (interrupted: True)."""
    import torch

    from policies.rollout.runner import PolicyRunner

    runner = PolicyRunner(opts.policy, seed=opts.seed, ema=opts.ema)
    rig, task = check_options(opts, runner)
    next_path, note = resolve_next(runner.meta, opts.next)
    if next_path is not None and opts.mode not in (None, "next"):
        raise UserError(f"the policy was trained on NEXT's tau_ext; --mode {opts.mode} would feed it another "
                        "estimate", where="--mode", fix="leave --mode out")
    realtime = opts.realtime or not rig.simulated
    lean = not realtime and (opts.lean if opts.lean is not None else
                             opts.record is None and opts.on_start is None)
    mode = "next" if next_path is not None else opts.mode
    if lean and not runner.force_names:
        mode = "none"  # the estimate is an input of the policy and a recorded topic only: nobody reads it
    plan = {"next_path": next_path, "note": note, "mode": mode, "lean": lean,
            "realtime": realtime, "threaded": opts.threaded if opts.threaded is not None else realtime,
            "schedule": opts.schedule or (ENSEMBLE if runner.policy == "act" else RECEDING),
            "k_exec": opts.k_exec or max(1, runner.cfg.chunk // K_EXEC_SHARE)}
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the loop keeps a core of its own; a chunk's work is small (docs/rollout.md)
    try:
        return _rollout(opts, runner, rig, task, **plan)
    finally:
        torch.set_num_threads(threads)


def _rollout(opts: RolloutOptions, runner, rig, task, *, next_path, note, mode, lean, realtime, threaded,
             schedule, k_exec) -> dict:
    from hardware.connect import open_rig
    from hardware.sim.twin import TwinDrivenClock

    schedule_mode = schedule
    t_wall = time.perf_counter()
    interrupted, rec_path = False, None
    # a twin's Dynamixel leader in process (the sdk's packet layer unchanged, no pty and no emulator thread
    # to hand the GIL to), as the demo does: in real time a pty thread costs the loop its p99 period
    transport = "inprocess" if rig.simulated else None
    with open_rig(rig, clock="realtime" if realtime else "lockstep", seed=opts.seed,
                  dynamixel_transport=transport) as s:
        clock = s.clock
        if realtime and s.twin is not None:  # the loop's thread steps the twin (as the demo does)
            s.twin.stop_realtime()
            clock = TwinDrivenClock(s.twin)
        ts = RolloutSession(s, TeleopOptions(mode=mode, checkpoint=str(next_path) if next_path else None),
                            clock=clock)
        pair = ts.pairs[0]
        if lean:  # the passive leader: nothing records or shows it, and the follower's law never reads it
            pair.serve_leader = False
            s.twin.set_idle(pair.leader.name)
        lim = pair.follower.safety.limits
        sched = ChunkSchedule(mode=schedule_mode, dt=runner.dt, q_min=lim.q_min, q_max=lim.q_max,
                              m=opts.ensemble_m, k_exec=k_exec)
        mc = pair.map.cfg
        grip_open = pair.map.gripper_forward(0.0) if task is not None else None
        fps = min((c.fps for c in rig.cameras if c.name in runner.cameras), default=30.0)
        max_age = FRAME_MAX_AGE_S if realtime else 1.0 / fps + 1e-6  # lockstep: the frame due last

        def frames(now):
            return ts.frames_at(now, runner.cameras, max_age, wait=not realtime)

        target = PolicyTarget(pair, runner, sched, frames=frames,
                              gripper_range=(mc.gripper_min, mc.gripper_max), gripper_open=grip_open)
        pair.target_fn = target
        stages = tuple(task.stages) if task is not None else ()

        def said(res):
            if opts.progress:
                print(episode_line(res, stages), flush=True)

        if task is not None:
            eps = TwinRollout(ts, task, opts.episodes, opts.seed, target,
                              opts.max_seconds or task.episode_s, on_episode=said)
            target.objects = lambda: _objects(eps)
        else:
            eps = MarkedRollout(ts, target, opts.episodes, stages, opts.max_seconds or MARK_TIME_LIMIT_S,
                                opts.marks, on_episode=said)
        periods: list[float] = []
        ts.hooks.append(eps.on_tick)
        ts.hooks.append(lambda r: periods.append(r.loop_period_s) if target.state == RUN else None)
        wire = WireCheck(lim)
        pair.follower.add_command_observer(wire)
        pair.leader.add_command_observer(wire.leader)
        if opts.record is not None:
            tname = task.name if task else ""
            rec = ts.record(opts.record, stem=f"rollout-{tname or rig.name}", task=tname,
                            extra_meta={"simulated": str(s.twin is not None).lower(), "operator": "policy",
                                        "policy": str(runner.path), "rollout_seed": opts.seed})
            rec_path = str(rec.path)
        runner.start(threaded)
        try:
            # frames only when the policy looks (else the recording starts the cameras with its first episode)
            problems = ts.start_cameras() if runner.cameras else []
            if problems:
                raise UserError(f"camera problem: {problems[0]}", where=str(rig.path),
                                fix="check the rig's cameras")
            if opts.progress:
                head = f"{runner.describe()}\n{ts.describe()[0]}, schedule {schedule_mode}, "
                print(head + ("real time" if realtime else "lockstep") + (f"\nnote: {note}" if note else ""),
                      flush=True)
            if opts.on_start is not None:
                opts.on_start(ts, target, eps)
            if isinstance(clock, TwinDrivenClock):
                clock.start()
            ts.loop.run()
        except KeyboardInterrupt:
            interrupted = True
        finally:
            runner.stop()
            ts.close_recording("rollout interrupted" if interrupted else "")
        holds = dict(pair.holds)
    res = eps.results
    out = {"simulated": rig.simulated, "rig": rig.name, "task": task.name if task else None,
           "policy": str(runner.path), "policy_kind": runner.policy, "method": runner.meta.get("method"),
           "schedule": schedule_mode, "k_exec": k_exec if schedule_mode == RECEDING else None,
           "ensemble_m": opts.ensemble_m if schedule_mode == ENSEMBLE else None, "seed": opts.seed,
           "feedback_mode": pair.mode, "next": str(next_path) if next_path else None, "note": render(note),
           "lean": lean,
           "interrupted": interrupted, "wall_s": time.perf_counter() - t_wall,
           "episodes": [{k: v for k, v in asdict(r).items() if k in ("index", "seed", "outcome", "progress",
                                                                    "stages", "duration_s")} for r in res],
           "success_rate": float(np.mean([r.outcome == "success" for r in res])) if res else 0.0,
           "mean_progress": float(np.mean([r.progress for r in res])) if res else 0.0,
           "stage_rates": {s: float(np.mean([r.stages.get(s) is not None for r in res])) if res else 0.0
                           for s in stages},
           "recording": rec_path}
    out["timing"] = timing_summary(periods, runner.latencies_s, target.ages_s, realtime, ts.rate_hz)
    out["timing"].update({"commands_sent": wire.sent, "command_violations": wire.violations,
                          "refused_nonfinite": sched.nonfinite,
                          "refused_outside_limits": sched.outside_limits,
                          "holds": holds, "targets_clamped": target.clamped,
                          "safety_clipped": int(pair.follower.safety.clipped),
                          "end_follower_held": wire.last_hold,
                          "end_leader_tau_max_nm": float(np.max(np.abs(wire.leader_tau)))
                          if wire.leader_tau is not None else None})
    out["timing"]["hold_times_s"] = wire.hold_times[:100]  # when the follower went on hold (loop clock)
    return out


def _objects(eps: TwinRollout) -> np.ndarray:
    from policies.privileged import task_state_vector

    return task_state_vector(eps.task, eps.model, eps.data, eps.params)
