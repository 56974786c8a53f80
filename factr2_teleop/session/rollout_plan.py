"""What a policy rollout is asked and what it decides before any device opens (session/rollout.py runs it).

    RolloutOptions   what the user chooses (`factr2 rollout`'s flags, the app's Rollout screen, a benchmark)
    RolloutHooks     what an app wires in: the operator's key queues and callbacks into the running session
    resolve_switches the tri-state switches (real time, takeover, lean, threaded inference) resolved, pure
    plan_rollout     the NEXT checkpoint, the estimator, the switches and the chunk schedule: a RolloutPlan
    check_options    everything refusable about the options, the policy and the rig (one line, UserError)
"""

from __future__ import annotations

import queue
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING

from calibration.next.ident import json_path, parse_ids
from hardware.errors import UserError
from hardware.features import rig_arm_names, rig_features
from hardware.reasons import Reason, messages
from policies.rollout.schedule import ACT_ENSEMBLE_M, ENSEMBLE, RECEDING

if TYPE_CHECKING:
    from factr2_teleop.session.rollout import RolloutSession
    from factr2_teleop.session.rollout_episodes import MarkedRollout, TwinRollout
    from factr2_teleop.session.rollout_pair import PolicyTarget
    from factr2_teleop.session.takeover_switch import Takeover
    from hardware.sim.faults import FaultSpec

    Episodes = TwinRollout | MarkedRollout  # the episode bookkeeping a hook is handed
    OnStart = Callable[[RolloutSession, PolicyTarget, Episodes], None]
    Operator = Callable[[RolloutSession, PolicyTarget, Episodes, Takeover], Callable]  # -> a per-tick hook

K_EXEC_SHARE = 3  # flow: by default a third of each chunk is executed (10 of 30 steps, 1/3 s at 30 Hz)


@dataclass
class RolloutOptions:
    """What the user chooses. rig: rig name or file; policy: RUN folder or step-*.json; task: a twin task
    (None: the operator marks episodes); episodes: how many; seed: episode k uses
    task_episodes.episode_seed(seed, k) like collection; record: folder for the MCAP; max_seconds: episode
    time limit [s] (default the task's); next: a NEXT checkpoint other than the policy's (said); realtime:
    wall-clock loop on a twin (timing); progress: print a line per episode. mode: estimator when the policy
    names no NEXT checkpoint (default the rig's); schedule: "ensemble" / "receding" (default ensemble, ACT and
    flow); ensemble_m; k_exec. The tri-state switches (None: resolve_switches decides): threaded: inference
    on its own thread (default: in real time only); lean: skip what only a recording or a watcher reads --
    the passive leader's simulation and service, and the estimator when the policy observes no force (default
    on for a lockstep twin without record and on_start; the follower's commands are the same either way,
    docs/rollout.md "Rollout CPU"); takeover: the leader follows and the operator can take over
    (session/rollout_takeover.py; default on in real time and with a scripted operator, off for a lockstep
    twin, where no hand acts)."""

    rig: str
    policy: Path
    task: str | None = None
    episodes: int = 1
    seed: int = 0
    record: Path | None = None
    record_cameras: bool = True  # the recording takes the rig's cameras' frames (`--no-cameras`: not)
    max_seconds: float | None = None  # s
    next: Path | None = None
    realtime: bool = False
    progress: bool = True
    mode: str | None = None
    schedule: str | None = None
    ensemble_m: float = ACT_ENSEMBLE_M
    k_exec: int | None = None
    threaded: bool | None = None
    lean: bool | None = None
    force: bool = False  # roll out on another task than the demonstrations' (session/task_check.py)
    ema: bool = True  # the checkpoint's moving-average weights where it has them (else the trained ones)
    takeover: bool | None = None
    faults: list[FaultSpec] | None = None  # the twin plays these (None: the rig's [twin] faults)
    force_input: str = "live"  # the policy's force input: live, or ablated (zero, shuffle; policies/rollout)


@dataclass
class RolloutHooks:
    """What an app wires into a rollout (none of it is a choice of the user's). marks: the keys s/y/n/q of
    operator-marked episodes (no twin task), put from any thread; on_start(session, target, episodes): once
    everything is built, before the loop runs (a UI's live view: add a tick hook, stop the loop); operator
    (session, target, episodes, takeover) -> a per-tick hook: the twin's scripted operator
    (tasks/takeover_operator.py); takeover_keys: the takeover key's (or pedal's) presses, from any thread."""

    marks: queue.SimpleQueue | None = None
    on_start: OnStart | None = None
    operator: Operator | None = None
    takeover_keys: queue.SimpleQueue = field(default_factory=queue.SimpleQueue)  # TOGGLE_KEY presses


@dataclass(frozen=True)
class Switches:
    """The tri-state switches of RolloutOptions, resolved."""

    realtime: bool
    takeover: bool
    lean: bool
    threaded: bool


def resolve_switches(opts: RolloutOptions, hooks: RolloutHooks, simulated: bool) -> Switches:
    """A real rig runs in real time; takeover defaults to on in real time or with a scripted operator; lean
    needs lockstep and no takeover, and defaults to on when nothing records or watches; inference runs on
    its own thread in real time unless asked."""
    realtime = opts.realtime or not simulated
    takeover = opts.takeover if opts.takeover is not None else (realtime or hooks.operator is not None)
    lean = not realtime and not takeover and (opts.lean if opts.lean is not None else
                                              opts.record is None and hooks.on_start is None)
    threaded = opts.threaded if opts.threaded is not None else realtime
    return Switches(realtime=realtime, takeover=takeover, lean=lean, threaded=threaded)


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


# -- the plan --------------------------------------------------------------------------------------------
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


def plan_rollout(opts: RolloutOptions, hooks: RolloutHooks, runner, rig) -> RolloutPlan:
    """The RolloutPlan of these options for the loaded policy (a PolicyRunner) on the checked rig;
    UserError when --mode would feed the policy another estimate than it was trained on."""
    next_path, note = resolve_next(runner.meta, opts.next)
    if next_path is not None and opts.mode not in (None, "next"):
        raise UserError(f"the policy was trained on NEXT's tau_ext; --mode {opts.mode} would feed it another "
                        "estimate", where="--mode", fix="leave --mode out")
    sw = resolve_switches(opts, hooks, rig.simulated)
    mode = estimator_mode(next_path, opts.mode, str(runner.meta.get("tau_ext_estimator", "")),
                          bool(runner.force_names))
    if sw.lean and not runner.force_names:
        mode = "none"  # the estimate is an input of the policy and a recorded topic only: nobody reads it
    return RolloutPlan(next_path=next_path, note=note, mode=mode, lean=sw.lean, realtime=sw.realtime,
                       threaded=sw.threaded,
                       schedule=opts.schedule or ENSEMBLE,  # flow too: docs/first.md "Chunk execution"
                       k_exec=opts.k_exec or max(1, runner.cfg.chunk // K_EXEC_SHARE), takeover=sw.takeover)


# -- refusals before a device opens ----------------------------------------------------------------------
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


def rig_follower_arms(rig) -> dict[str, tuple[str, list[str]]]:
    """The rig's follower arms by recorded name: (arm model, joint names): what a policy is checked
    against."""
    from hardware.arms import load_arm

    out = {}
    for (_lead, fol), (_p, arm) in zip(rig.pairs, rig_arm_names(rig)):
        spec = rig.device(fol)
        out[arm] = (spec.arm, list(load_arm(spec.arm).joint_names))
    return out
