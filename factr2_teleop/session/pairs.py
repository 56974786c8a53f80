"""Building a rig's arm pairs for teleop, once for the CLI, the terminal app, the demo and task collection:
the rig's [teleop] table, the feedback mode and its estimator, the leader's model, on top the caller's
TeleopOptions. Same options in, same pairs out, whoever calls.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from calibration.estimators import (
    DOB_GAIN_PER_S,
    FEEDBACK_MODES,
    PP_STIFFNESS_NM_PER_RAD,
    SIMULATED_ONLY_MODES,
    make_estimator,
)
from factr2_teleop.teleop.leader_law import arm_model_fns, leader_gravity_file
from factr2_teleop.teleop.loop import DEFAULT_RATE_HZ
from factr2_teleop.teleop.pair import ArmPair, PairConfig
from hardware.errors import ConfigError, UserError
from hardware.features import pair_names

MODE_HELP = ("feedback mode (default: the rig's [teleop] feedback_mode, else next when a NEXT checkpoint is "
             "configured, else dob; ground_truth only on a twin)")


@dataclass
class TeleopOptions:
    """What a user can choose for a teleop session; None keeps the rig's (or the default) value.

    mode: FEEDBACK_MODES; checkpoint: NEXT checkpoint for every follower (mode next); rate_hz: loop rate [Hz];
    gain: feedback gain K_f [leader N*m per follower N*m], one value or one per joint; feedback: other
    FeedbackConfig keys over the rig's (clip_nm, t_high_nm, t_low_nm, ...); pp_stiffness_nm_per_rad and
    dob_gain_per_s: the pp and dob estimators' constants; next_worker: see below."""

    mode: str | None = None
    checkpoint: str | None = None
    rate_hz: float | None = None
    gain: float | list | None = None
    feedback: dict = field(default_factory=dict)
    pp_stiffness_nm_per_rad: float | list = PP_STIFFNESS_NM_PER_RAD
    dob_gain_per_s: float | list = DOB_GAIN_PER_S
    # NEXT in its own process on a real-time clock (calibration/next/worker.py): its LSTM off the loop's
    # thread; False keeps it inline. Lockstep clocks always run it inline (determinism).
    next_worker: bool = True


def rig_tables(rig) -> tuple[dict[str, dict], dict]:
    """(PairConfig tables by pair name, loop options {feedback_mode, rate_hz}) from the rig's [teleop]."""
    table = dict(getattr(rig, "teleop", {}) or {})
    per = table.pop("pairs", {}) or {}
    opts = {k: table.pop(k) for k in ("feedback_mode", "rate_hz") if k in table}
    out = {}
    for name, (_lead, fol) in zip(pair_names(rig), rig.pairs):
        out[name] = {**table, **(per.get(name) or per.get(fol) or {}), "name": name}
    return out, opts


def loop_rate_hz(rig, opts: TeleopOptions) -> float:
    rate = float(opts.rate_hz or rig_tables(rig)[1].get("rate_hz", DEFAULT_RATE_HZ))
    if not rate > 0:
        raise UserError(f"loop rate {rate} Hz must be > 0", where="--rate", fix="use e.g. 500")
    return rate


def follower_checkpoint(spec, opts: TeleopOptions) -> str | None:
    return opts.checkpoint or spec.next_checkpoint


def feedback_mode(rig, spec, opts: TeleopOptions) -> str:
    """The mode a follower runs: the option, else the rig's, else next with a checkpoint, else dob."""
    mode = opts.mode or rig_tables(rig)[1].get("feedback_mode") or (
        "next" if follower_checkpoint(spec, opts) else "dob")
    if mode not in FEEDBACK_MODES:
        raise ConfigError(f"unknown feedback mode {mode!r}", where=f"{rig.path}: [teleop] feedback_mode",
                          fix=f"use one of {', '.join(FEEDBACK_MODES)}")
    if mode in SIMULATED_ONLY_MODES and not rig.simulated:
        raise UserError(f"{mode} feedback exists only on simulated rigs", where="feedback mode",
                        fix="use dob, pp or next")
    return mode


def check_options(rig, opts: TeleopOptions) -> None:
    """Refuse options the rig cannot run before anything is opened (UserError / ConfigError)."""
    loop_rate_hz(rig, opts)
    for _lead, fol in rig.pairs:
        feedback_mode(rig, rig.device(fol), opts)


def modes_for(rig) -> list[str]:
    """Feedback modes a rig can run (ground truth only on a twin)."""
    return [m for m in FEEDBACK_MODES if rig.simulated or m not in SIMULATED_ONLY_MODES]


def load_next(path: str | Path, arm: str):
    """The streaming NEXT estimator of a checkpoint (UserError if it was trained for another arm or is
    missing). Its work is spread over the ticks between two samples (defer; the pair calls idle())."""
    from calibration.next.checkpoint import load_checkpoint
    from calibration.next.estimator import NextEstimator

    p = Path(path) if Path(path).is_dir() else Path(path).with_suffix(".json")  # a folder: official layout
    if not p.exists():
        raise UserError(f"NEXT checkpoint {p} not found", where="NEXT checkpoint",
                        fix="run `factr2 calibrate` (or the Calibration screen) first, or pick another mode")
    return NextEstimator(load_checkpoint(p, arm=arm), defer=True, source=(str(p), arm))


def pair_estimator(mode: str, session, fspec, follower, opts: TeleopOptions, rate_hz: float, next_est=None):
    """The estimator of one follower for a mode (None for "none"). next_est: a NEXT estimator already loaded
    (the demo's cache), else the checkpoint of the options or the rig is loaded."""
    truth = None
    if session.twin is not None:
        twin, name, n = session.twin, fspec.name, follower.n_joints
        truth = lambda: twin.device_ground_truth(name, 1.0 / rate_hz).tau_ext[:n]  # noqa: E731 (tick mean)
    if mode == "next" and next_est is None:
        ck = follower_checkpoint(fspec, opts)
        if not ck:
            raise UserError(f"no NEXT checkpoint for follower {fspec.name}", where="feedback mode next",
                            fix="pass --checkpoint DIR/next.json (from `factr2 calibrate`) or set "
                                "next_checkpoint in the rig")
        next_est = load_next(ck, fspec.arm)
    if mode == "next" and opts.next_worker and session.clock.realtime and getattr(next_est, "source", None):
        from calibration.next.worker import NextWorker

        return NextWorker.of(next_est, follower.n_joints, 1.0 / rate_hz)
    return make_estimator(mode, follower.n_joints, follower_arm=fspec.arm, dob_gain=opts.dob_gain_per_s,
                          pp_stiffness_nm_per_rad=opts.pp_stiffness_nm_per_rad, next_estimator=next_est,
                          loop_period_s=1.0 / rate_hz, truth=truth)


def pair_config(table: dict, mode: str, opts: TeleopOptions, where: str) -> PairConfig:
    """The rig's table for one pair with the mode's feedback settings and the options on top."""
    cfg = PairConfig.from_dict(table, where=where)
    fb = cfg.law.feedback
    fb.enabled = mode != "none"
    fb.gate_on_contact = mode != "pp"  # position-position feeds the lag back always (no contact gate)
    if opts.gain is not None:
        fb.gain = opts.gain if isinstance(opts.gain, list) else float(opts.gain)
    for k, v in opts.feedback.items():
        if not hasattr(fb, k):
            raise ConfigError(f"unknown feedback setting {k!r}", where=where, fix="see docs/teleop.md")
        setattr(fb, k, v)
    return cfg


def build_pairs(session, opts: TeleopOptions, next_estimators: dict | None = None,
                pair_class: type[ArmPair] = ArmPair) -> list[ArmPair]:
    """One ArmPair per rig pair (UserError/ConfigError when one cannot be built; nothing is commanded).
    next_estimators: follower name -> an already loaded NEXT estimator (optional); pair_class: an ArmPair
    subclass with another per-tick law (the policy rollout's), built from the same pieces."""
    rig = session.rig
    if not rig.pairs:
        raise ConfigError("the rig pairs no leader with a follower", where=str(rig.path),
                          fix="add a [[pairs]] table or a leader")
    rate = loop_rate_hz(rig, opts)
    tables, _ = rig_tables(rig)
    pairs = []
    for name, (lname, fname) in zip(pair_names(rig), rig.pairs):
        lspec, fspec = rig.device(lname), rig.device(fname)
        leader, follower = session.leaders[lname], session.followers[fname]
        mode = feedback_mode(rig, fspec, opts)
        cfg = pair_config(tables[name], mode, opts, where=f"{rig.path}: [teleop] {name}")
        est = pair_estimator(mode, session, fspec, follower, opts, rate, (next_estimators or {}).get(fname))
        grav, jac = arm_model_fns(lspec.arm, leader_gravity_file(rig, lname))  # identified g(q), if any
        pairs.append(pair_class(leader, follower, cfg, 1.0 / rate, gravity_fn=grav, jacobian_fn=jac,
                                estimator=est, mode=mode))
    return pairs
