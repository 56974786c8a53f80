"""`factr2 demo`: the main job on the built-in twin (SIMULATED): sim-piper + virtual operator + a table
contact/wipe task with bilateral force feedback; NEXT from a checkpoint it finds cached or trains first.

    factr2 demo [--headless] [--seconds 60] [--json FILE] [--record DIR]
                [--mode auto|none|dob|pp|next|ground_truth]
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

from calibration.estimators import FEEDBACK_MODES
from hardware.errors import UserError

HELP = "SIMULATED bilateral teleop demo on the twin: virtual operator, table wipe, timing + feedback metrics"
MODES = ("auto", *FEEDBACK_MODES)


def add_arguments(p) -> None:
    p.add_argument("--headless", action="store_true", help="no live view: run, then print a summary")
    p.add_argument("--seconds", type=float, default=60.0, help="task length [s] (default 60)")
    p.add_argument("--json", metavar="FILE", help="write the metrics as JSON (see docs/demo.md)")
    p.add_argument("--record", metavar="DIR", help="record the run (MCAP) into this folder")
    p.add_argument("--mode", choices=MODES, default="auto",
                   help="feedback mode (default auto: NEXT, trained on the twin first if none is cached)")
    p.add_argument("--checkpoint", metavar="NEXT.json", help="NEXT checkpoint to use instead of the cache")
    p.add_argument("--no-calibrate", action="store_true",
                   help="auto mode: do not train NEXT when none is cached (use the disturbance observer)")
    p.add_argument("--rig", default="sim-piper", help="simulated rig (default sim-piper)")
    p.add_argument("--rate", type=float, default=500.0, help="loop rate [Hz] (default 500)")
    p.add_argument("--clock", choices=("realtime", "lockstep"), default="realtime",
                   help="realtime (timing numbers mean something; default) or lockstep (deterministic)")


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def resolve_mode(args) -> tuple[str, Path | None, str | None]:
    """(mode, NEXT checkpoint or None, why NEXT is not used or None)."""
    from factr2_teleop.session import next_cache

    if args.mode not in ("auto", "next"):
        return args.mode, None, None
    path = next_cache.find_checkpoint(args.rig, args.checkpoint)
    if path is None and args.mode == "auto" and args.no_calibrate:
        return "dob", None, "no cached NEXT checkpoint (--no-calibrate)"
    if path is None:
        _say(f"no NEXT checkpoint for {args.rig} yet: one-time set-up on the twin "
             f"({next_cache.DEMO_MINUTES:g} min of SIMULATED free motion as fast as the CPU goes, then at "
             f"most {next_cache.DEMO_TRAIN_S:.0f} s of training; progress shown)")
        show = sys.stderr.isatty()
        last = [0.0]

        def progress(done_s: float, total_s: float) -> None:
            now = time.monotonic()
            if show and now - last[0] > 0.5:
                last[0] = now
                print(f"\r  free motion {done_s:5.1f} / {total_s:.0f} s", end="", file=sys.stderr, flush=True)

        try:
            path = next_cache.create_checkpoint(args.rig, _say, progress=progress)
        except Exception as e:  # noqa: BLE001 -- set-up failure: say it, then run with the observer
            if show:
                print(file=sys.stderr)
            if args.mode == "next":
                raise UserError(f"NEXT set-up failed ({type(e).__name__}: {e})", where="factr2 demo",
                                fix="train one with `factr2 calibrate --rig sim-piper --out DIR` and pass "
                                    "--checkpoint DIR/next.json") from None
            return "dob", None, f"NEXT set-up failed ({type(e).__name__}: {str(e)[:120]})"
        if show:
            print(file=sys.stderr)
    return "next", path, None


def _live_text(run, stop: threading.Event) -> None:
    """One status line, rewritten in place, until the run ends (the Textual app has no demo view yet)."""
    while not stop.wait(0.5):
        s = run.loop.snapshot()
        rec = s.records.get("arm")
        phase = s.phases.get("arm", "?")
        ops = run.operator.log
        task = ops[-1].phase if ops else "-"
        gate = rec.gate if rec is not None else 0.0
        print(f"\r[SIMULATED {run.cfg.mode}] t {s.t - run.operator.t0 if ops else 0.0:5.1f} s  {phase:10s} "
              f"task {task:8s} gate {gate:4.2f} | {s.timing.line()}   ", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)


def tui_view():
    """The terminal app's demo view, when it provides one: factr2_teleop.tui.demo_view.show_demo(run,
    worker) shows DemoRun `run` live (run.loop.snapshot(), run.operator.log) while thread `worker` runs it,
    returns when the run ends or the user quits (then it calls run.loop.stop()), with a line
    saying how the run ended ("finished", "emergency stop: ...", ...). None until it exists."""
    try:
        from factr2_teleop.tui import demo_view
    except ImportError:
        return None
    return getattr(demo_view, "show_demo", None)


def run(args) -> int:
    from factr2_teleop.demo.task import DemoConfig, DemoRun
    from hardware.rigs.rig import load_rig

    if not args.seconds > 0 or not args.rate > 0:
        raise UserError("--seconds and --rate must be > 0", where="factr2 demo", fix="e.g. --seconds 60")
    if not load_rig(args.rig).simulated:
        raise UserError(f"rig {args.rig} is real hardware; the demo runs on a twin", where="--rig",
                        fix=f"use `factr2 teleop --rig {args.rig}` on real arms, or a sim-* rig here")
    from factr2_teleop.session.pairs import load_next

    mode, next_path, why = resolve_mode(args)
    next_est = load_next(next_path, load_rig(args.rig).followers[0].arm) if next_path is not None else None
    live = not args.headless and sys.stderr.isatty() and sys.stdout.isatty()
    # imported before the rig opens: a real-time run must start right after DemoRun() (its twin waits)
    show_app = tui_view() if live else None
    if why:
        _say(f"feedback mode {mode}: {why}")
    demo = DemoRun(DemoConfig(rig=args.rig, seconds=args.seconds, mode=mode, rate_hz=args.rate,
                              clock=args.clock), next_source=next_est,
                   next_path=str(next_path) if next_path else None)
    rec = None
    try:
        if args.record:
            rec = demo.teleop.record(args.record, stem=f"demo-{args.rig}",
                                     extra_meta={"demo": "table wipe, virtual operator (SIMULATED)"})
            rec.start_episode("demo: press and wipe the table")
        stop_view = threading.Event()
        view = None
        if live and show_app is None:
            view = threading.Thread(target=_live_text, args=(demo, stop_view), daemon=True)
            view.start()
        _say(f"SIMULATED demo on {args.rig}: {args.seconds:g} s, feedback {mode}, {args.rate:g} Hz "
             f"({args.clock}); Ctrl-C stops (leader zero torque, follower holds)")
        worker = threading.Thread(target=demo.run, name="factr2-demo", daemon=True)
        worker.start()
        try:
            if show_app is not None:
                how = show_app(demo, worker)
                if worker.is_alive():  # the user left the app early
                    demo.loop.stop(timeout_s=2.0)
                if isinstance(how, str) and how != "finished":
                    _say(f"live view: {how}")
            while worker.is_alive():
                worker.join(0.2)
        except KeyboardInterrupt:
            demo.loop.stop(timeout_s=2.0)  # the loop leaves both arms safe
            if worker.ident is not None:
                worker.join(2.0)
            _say("stopped by Ctrl-C: leader at zero torque, follower holding")
        finally:
            stop_view.set()
            if view is not None:
                view.join(1.0)
        if demo.loop.error is not None:
            raise UserError(f"demo stopped: {demo.loop.error}", where="factr2 demo",
                            fix="see the messages above")
        res = demo.result()
    finally:
        if rec is not None:
            st = demo.teleop.close_recording()
            _say(f"recorded to {rec.path}" + (f" (error: {st.error})" if st.error else ""))
        demo.close()
    out = res.to_json()
    if why:
        out["next_unavailable"] = why
    _print_summary(out)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1))
        _say(f"wrote {args.json}")
    return 0


def _print_summary(d: dict) -> None:
    def f(x, fmt):
        return "--" if x is None else format(x, fmt)

    share = None if d.get("loop_cpu_share") is None else 100 * d["loop_cpu_share"]
    print(f"SIMULATED demo ({d['mode']}, {d['clock']} clock, {d['seconds']:g} s):")
    print(f"  loop {f(d['loop_hz'], '.1f')} Hz, period p50 {f(d['period_p50_ms'], '.2f')} ms "
          f"p99 {f(d['period_p99_ms'], '.2f')} ms max {f(d['period_max_ms'], '.1f')} ms, "
          f"{d['overruns']} overruns / {d['ticks']} ticks, "
          f"CPU {f(d['cpu_ms_per_tick'], '.2f')} ms/tick (process), loop thread "
          f"{f(d.get('loop_cpu_ms_per_tick'), '.2f')} ms/tick = {f(share, '.0f')} % of the period "
          f"(+ {f(d.get('loop_twin_cpu_ms_per_tick'), '.2f')} ms/tick of twin work on its thread"
          + (f"; NEXT in its own process {d['next_worker_cpu_ms_per_tick']:.2f} ms/tick"
             if d.get("next_worker_cpu_ms_per_tick") is not None else "") + ")")
    print(f"  feedback_corr {f(d['feedback_corr'], '.3f')}, "
          f"feedback_lag {f(d['feedback_lag_ms'], '.1f')} ms, "
          f"tau_ext L1 contact {f(d['tau_ext_l1_contact'], '.2f')} / "
          f"free {f(d['tau_ext_l1_free'], '.2f')} N*m")
    print(f"  hand push into the table {f(d['hand_push_n'], '.2f')} N, command violations "
          f"{d['max_command_violation']}")
    print(f"  holds {d['holds']} ({f(d['hold_s'], '.2f')} s on hold), refused resumes {d['refused_resumes']}")
