"""`factr2 teleop --rig R [--record DIR]`: bilateral force-feedback teleop on a rig (real arms or a twin).

One loop, one thread, every leader/follower pair of the rig (bimanual rigs run both) at --rate Hz. The
rig's [teleop] table (optional) sets the pair configuration (factr2_teleop.teleop.pair.PairConfig keys;
a `pairs.<name>` sub-table per pair; `feedback_mode` and `rate_hz` too). Ctrl-C stops: every leader at
zero torque, every follower holding.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

from hardware.errors import ConfigError, UserError

HELP = "bilateral force-feedback teleop on a rig (Ctrl-C stops: leader zero torque, follower holds)"
MODES = ("none", "dob", "pp", "next", "ground_truth")
PP_STIFFNESS_NM_PER_RAD = 40.0  # position-position coupling stiffness (follower N*m per rad of lag)


def add_arguments(p) -> None:
    p.add_argument("--rig", required=True, help="built-in rig name or path to a rig .toml")
    p.add_argument("--record", metavar="DIR", help="record the session (MCAP) into this folder")
    p.add_argument("--mode", choices=MODES, help="feedback mode (default: rig [teleop] feedback_mode, else "
                   "next when the follower has a next_checkpoint, else dob)")
    p.add_argument("--checkpoint", metavar="NEXT.json", help="NEXT checkpoint (mode next; all followers)")
    p.add_argument("--rate", type=float, help="loop rate [Hz] (default: rig [teleop] rate_hz, else 500)")
    p.add_argument("--seconds", type=float, help="stop after this long (default: until Ctrl-C)")


def pair_configs(rig) -> tuple[dict, dict]:
    """(per-pair PairConfig dicts by pair name, loop options) from the rig's raw [teleop] table."""
    table = dict(getattr(rig, "teleop", {}) or {})
    per = table.pop("pairs", {}) or {}
    opts = {k: table.pop(k) for k in ("feedback_mode", "rate_hz") if k in table}
    out = {}
    for _lead, fol in rig.pairs:
        name = fol if len(rig.pairs) > 1 else "arm"
        out[name] = {**table, **(per.get(name) or per.get(fol) or {}), "name": name}
    return out, opts


def _estimator(mode: str, spec, follower, session, checkpoint: str | None, rate_hz: float):
    from factr2_teleop.teleop.estimators import make_estimator

    if mode == "ground_truth" and session.twin is None:
        raise UserError("ground_truth feedback exists only on simulated rigs", where="--mode",
                        fix="use dob, pp or next")
    src, period = None, 0.0
    if mode == "next":
        from factr2_teleop.demo.next_cache import load_estimator

        path = checkpoint or spec.next_checkpoint
        if not path:
            raise UserError(f"no NEXT checkpoint for follower {spec.name}", where="--mode next",
                            fix="pass --checkpoint DIR/next.json (from `factr2 calibrate`) or set "
                                "next_checkpoint in the rig")
        src = load_estimator(Path(path).with_suffix(".json"), spec.arm)
        period = 1.0 / src.ck.rate_hz - 0.25 / rate_hz
    truth = None
    if session.twin is not None:
        twin, name = session.twin, spec.name
        truth = lambda: twin.device_ground_truth(name, 1.0 / rate_hz).tau_ext  # noqa: E731  (tick mean)
    est = make_estimator(mode, follower.n_joints, follower_arm=spec.arm, next_source=src, truth=truth,
                         pp_stiffness_nm_per_rad=PP_STIFFNESS_NM_PER_RAD)
    return est, period


def run(args) -> int:
    from factr2_teleop.teleop.leader_law import arm_model_fns
    from factr2_teleop.teleop.loop import TeleopLoop
    from factr2_teleop.teleop.pair import ArmPair, PairConfig
    from factr2_teleop.teleop.rt import single_thread_blas
    from hardware.rigs.rig import load_rig
    from hardware.sim import open_rig

    single_thread_blas()
    rig = load_rig(args.rig)
    cfgs, opts = pair_configs(rig)
    rate = float(args.rate or opts.get("rate_hz", 500.0))
    if not rate > 0:
        raise UserError(f"rate {rate} must be > 0", where="--rate", fix="use e.g. 500")
    if args.mode == "ground_truth" and not rig.simulated:
        raise UserError("ground_truth feedback exists only on simulated rigs", where="--mode",
                        fix="use dob, pp or next")
    session = open_rig(rig, clock="realtime")
    loop = None
    rec = None
    try:
        pairs = []
        for (lead_name, fol_name), name in zip(session.rig.pairs, cfgs):
            lspec, fspec = session.rig.device(lead_name), session.rig.device(fol_name)
            leader, follower = session.leaders[lead_name], session.followers[fol_name]
            has_next = bool(args.checkpoint or fspec.next_checkpoint)
            mode = args.mode or opts.get("feedback_mode") or ("next" if has_next else "dob")
            if mode not in MODES:
                raise ConfigError(f"unknown feedback_mode {mode!r}", where=f"{rig.path}: [teleop]",
                                  fix=f"use one of {', '.join(MODES)}")
            cfg = PairConfig.from_dict(cfgs[name], where=f"{rig.path}: [teleop]")
            if mode == "pp":
                cfg.law.feedback.gate_on_contact = False
            est, period = _estimator(mode, fspec, follower, session, args.checkpoint, rate)
            cfg.estimator_period_s = max(cfg.estimator_period_s, period)
            g, jac = arm_model_fns(lspec.arm)
            pairs.append(ArmPair(leader, follower, cfg, 1.0 / rate, gravity_fn=g, jacobian_fn=jac,
                                 estimator=est))
            print(f"{name}: {lead_name} -> {fol_name}, feedback {mode}"
                  + (" (SIMULATED twin)" if session.simulated else ""), file=sys.stderr)
        hook = None
        if args.record:
            rec, hook = _recorder(args.record, session, pairs)
        loop = TeleopLoop(pairs, session.clock, rate_hz=rate, recorder=hook)
        loop.start(duration_s=args.seconds)
        _watch(loop)
    finally:
        if loop is not None:
            loop.stop(timeout_s=2.0)  # leaders zero torque, followers hold (also after Ctrl-C)
        if rec is not None:
            st = rec.close()
            print(f"recorded to {rec.path}" + (f" (error: {st.error})" if st.error else ""), file=sys.stderr)
        session.close()
    if loop.error is not None and not isinstance(loop.error, KeyboardInterrupt):
        raise UserError(f"teleop stopped: {loop.error}", where="factr2 teleop", fix="see the messages above")
    print(loop.timing.stats().line())
    return 0


def _watch(loop) -> None:
    """Status line until the loop ends or Ctrl-C (which the finally in run() turns into a safe stop)."""
    seen = 0
    tty = sys.stderr.isatty()
    try:
        while True:
            time.sleep(0.5)
            s = loop.snapshot()
            for _t, who, text in s.messages[seen:]:
                print(("\n" if tty else "") + f"{who}: {text}", file=sys.stderr)
            seen = len(s.messages)
            if tty:
                phases = " ".join(f"{k}:{v}" for k, v in s.phases.items())
                print(f"\r{phases} | {s.timing.line()}   ", end="", file=sys.stderr, flush=True)
            if not loop.running and loop._thread is not None and not loop._thread.is_alive():
                break
    except KeyboardInterrupt:
        print("\nCtrl-C: stopping (leaders zero torque, followers hold)", file=sys.stderr)
    if tty:
        print(file=sys.stderr)


def _recorder(dir_: str, session, pairs):
    from hardware.recording.session import describe_session
    from hardware.recording.writer import Recorder

    out = Path(dir_)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{session.rig.name}-{time.strftime('%Y%m%d-%H%M%S')}.mcap"
    rec = Recorder(path, t0=session.clock.now(),
                   metadata=describe_session(rig_path=session.rig.path, twin=session.simulated,
                                             next_checkpoint=""))
    rec.start_episode(session.clock.now(), "teleop")
    by_name = {p.cfg.name: p for p in pairs}
    lock = threading.Lock()

    def hook(r: dict) -> None:
        p = by_name[r["pair"]]
        pre = "" if len(pairs) == 1 else f"{r['pair']}_"
        t = r["t"]
        with lock:
            rec.log_joint_state(f"{pre}leader", t, p.leader.last_state)
            rec.log_joint_state(f"{pre}follower", t, p.follower.last_state)
            rec.log_external_torque(f"{pre}follower", t, r["follower.joint.tau_ext"], r["feedback.contact"])
            rec.log_torque_command(f"{pre}leader", t, r["leader.joint.tau_cmd"], r["feedback.gate"])

    return rec, hook
