"""`factr2 teleop --rig R [--record DIR]`: bilateral force-feedback teleop on a rig (real arms or a twin).

One loop, one thread, every leader/follower pair of the rig (bimanual rigs run both) at --rate Hz, built by
the session layer (factr2_teleop.session) exactly as the terminal app and the demo build it. The rig's
[teleop] table sets the pair configuration (docs/teleop.md). --record writes one MCAP per run with the
rig's cameras. Ctrl-C stops: every leader at zero torque, every follower holding.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time

from factr2_teleop.commands._twin_fault import add_twin_fault_argument, twin_faults
from hardware.errors import UserError

STATUS_EVERY_S = 0.5  # s between status lines
# s: how often the watcher looks whether the loop ended (slept, not a join on the loop's thread: a join that
# Ctrl-C interrupts marks a running thread stopped on CPython 3.11, bpo-45274, and the arms were then
# disconnected under a loop still ticking)
WATCH_POLL_S = 0.02
HELP = "bilateral force-feedback teleop on a rig (Ctrl-C stops: leader zero torque, follower holds)"


def add_arguments(p) -> None:
    from calibration.estimators import FEEDBACK_MODES
    from factr2_teleop.session.pairs import MODE_HELP

    p.add_argument("--rig", required=True, help="built-in rig name or path to a rig .toml")
    p.add_argument("--record", metavar="DIR", help="record the run (MCAP, with the rig's cameras) in DIR")
    p.add_argument("--no-cameras", action="store_true", help="record without the rig's cameras")
    p.add_argument("--mode", choices=FEEDBACK_MODES, help=MODE_HELP)
    p.add_argument("--checkpoint", metavar="NEXT.json", help="NEXT checkpoint (mode next; all followers)")
    p.add_argument("--rate", type=float, help="loop rate [Hz] (default: rig [teleop] rate_hz, else 500)")
    p.add_argument("--seconds", type=float, help="stop after this long (default: until Ctrl-C)")
    add_twin_fault_argument(p)


def options(args):
    """The session layer's TeleopOptions of these arguments."""
    from factr2_teleop.session.pairs import TeleopOptions

    return TeleopOptions(mode=args.mode, checkpoint=args.checkpoint, rate_hz=args.rate)


def execute(args) -> dict:
    """Run the session; {"timing": TimingStats, "recording": path or None, "status": RecorderStatus or None,
    "cameras": {name: CameraStats}, "messages": [(t, who, text)]}
    (bench/bench_teleop_record.py measures through this). BLAS on one thread while it runs, for this process
    and the ones it starts (hardware/threads.py)."""
    from hardware.threads import limit_threads

    with limit_threads(1, blas=True, env=True):
        return _execute(args)


def _execute(args) -> dict:
    from factr2_teleop.session.pairs import check_options
    from factr2_teleop.session.teleop import TeleopSession
    from hardware.connect import open_rig
    from hardware.rigs.rig import load_rig

    rig = load_rig(args.rig)
    opts = options(args)
    check_options(rig, opts)
    session = open_rig(rig, clock="realtime", faults=twin_faults(args))
    ts, out = None, {"recording": None, "status": None, "cameras": {}}
    try:
        ts = TeleopSession(session, opts)
        for line in ts.describe():
            print(line, file=sys.stderr)
        rec = ts.record(args.record, cameras=not args.no_cameras) if args.record else None
        # the arms put down by the loop's own thread as it ends (not after this thread notices: on a slowed
        # core that took over a leader's 100 ms Bus Watchdog, issue #53); _stop below passes over them then
        ts.loop.on_end.append(session.disconnect_arms)
        ts.loop.start(duration_s=args.seconds)  # at once: a twin's unheld leader sinks until the loop runs
        if rec is not None:
            # the episode opens, then the cameras (a second or so): every frame they capture lies in it
            rec.start_episode("teleop")
            for line in ts.start_cameras() if not args.no_cameras else []:  # (they run: their failures)
                print(f"recording without it: {line}", file=sys.stderr)
        _watch(ts.loop)
    finally:
        with _ctrl_c_held():  # a Ctrl-C now (the loop ended by itself, or a second one) would cut the stop
            _stop(ts, session, out)
    loop = ts.loop
    if loop.error is not None and not isinstance(loop.error, KeyboardInterrupt):
        raise UserError(f"teleop stopped: {loop.error}", where="factr2 teleop", fix="see the messages above")
    out["timing"] = loop.timing.stats(whole_run=True)  # the whole session, not its last seconds
    out["messages"] = list(loop.snapshot().messages)  # (t [s], who, text): holds, notes
    twin = session.twin
    out["faults"] = list(twin.faults.log) if twin is not None and twin.faults is not None else []
    out["twin_t_offset_s"] = twin.rig_time() - twin.t if twin is not None else None  # rig - twin clock [s]
    return out


def _stop(ts, session, out: dict) -> None:
    """The safe stop: the loop stopped, the arms put down, the recording closed (its status into out)."""
    if ts is not None:
        ts.loop.stop(timeout_s=2.0)  # leaders zero torque, followers hold (also after Ctrl-C)
    if ts is None or not ts.loop.alive:  # (a loop stuck in a driver call: session.close() below)
        # the arms put down at once, before the recording's close (a second or so): a leader left that
        # long without a packet latches its Bus Watchdog, a Damiao motor drops to damping
        session.disconnect_arms()
    if ts is not None:
        rec = ts.recording
        st = ts.close_recording("teleop stopped")
        if st is not None:
            out.update(recording=rec.path, status=st, cameras=rec.camera_stats)
            err = f" (error: {st.error})" if st.error else ""
            print(f"recorded to {rec.path}{err}: {st.messages_written} messages, {st.frames_written} "
                  f"frames, dropped {st.dropped_samples} samples / {st.dropped_frames} frames",
                  file=sys.stderr)
            _camera_lines(rec.camera_stats)
    session.close()


@contextlib.contextmanager
def _ctrl_c_held():
    """While the arms are put down and the recording closes, the first Ctrl-C is said, not raised (raised, it
    would leave the recording unclosed and the rig open); a further one raises as usual (an operator who
    insists). Main thread only: elsewhere no handler can be set, nor would one be called."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    prev = signal.getsignal(signal.SIGINT) or signal.default_int_handler  # (None: set outside Python)

    def held(signum, frame):
        print("\nCtrl-C: already stopping (arms down, recording closing); Ctrl-C again to abort",
              file=sys.stderr)
        signal.signal(signal.SIGINT, prev)

    signal.signal(signal.SIGINT, held)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, prev)


def run(args) -> int:
    print(execute(args)["timing"].line())
    return 0


def _camera_lines(stats: dict) -> None:
    for name, s in stats.items():
        extra = f", {s.failed} failed ({s.error})" if s.failed else ""
        print(f"camera {name}: {s.captured} / {s.expected} frames ({100 * s.ratio:.1f} %), "
              f"{s.dropped} dropped{extra}", file=sys.stderr)


def _watch(loop) -> None:
    """Status line until the loop ends (seen within WATCH_POLL_S) or Ctrl-C (which the finally in run()
    turns into a safe stop)."""
    seen = 0
    tty = sys.stderr.isatty()
    t_next = time.monotonic() + STATUS_EVERY_S
    try:
        while loop.alive:
            time.sleep(WATCH_POLL_S)
            if time.monotonic() < t_next and loop.alive:
                continue
            t_next += STATUS_EVERY_S
            s = loop.snapshot()
            for _t, who, text in s.messages[seen:]:
                print(("\n" if tty else "") + f"{who}: {text}", file=sys.stderr)
            seen = len(s.messages)
            if tty:
                phases = " ".join(f"{k}:{v}" for k, v in s.phases.items())
                print(f"\r{phases} | {s.timing.line()}   ", end="", file=sys.stderr, flush=True)
    except KeyboardInterrupt as e:
        why = "SIGTERM" if str(e) == "SIGTERM" else "Ctrl-C"
        print(f"\n{why}: stopping (leaders zero torque, followers hold)", file=sys.stderr)
        if why == "SIGTERM":
            raise  # after the safe stop (execute's finally), the CLI exits 143
    if tty:
        print(file=sys.stderr)
