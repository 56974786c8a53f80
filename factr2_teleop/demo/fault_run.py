"""A lockstep twin teleop run with scheduled faults, and what happened (SIMULATED; tests/test_faults_*.py and
bench/faults.py measure through this).

    out = run_with_faults([parse_fault("can_busoff@1.0:0.3")], seconds=2.5)
    out.safe_ms    # per injected fault: ms from its start to the first follower hold on the wire (None: none)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from factr2_teleop.demo.task import DemoConfig, DemoRun
from factr2_teleop.teleop.pair import COUPLED, SOFT_START
from hardware.errors import UserError
from hardware.types import STATUS_COMM_LOST, STATUS_STALE

RATE_HZ = 250.0  # Hz: the lockstep loop rate of fault runs (a few seconds of twin time each)
REACT_WINDOW_S = 0.1  # s: a hold up to this long after a fault ends is the reaction to it (not a later one)


@dataclass
class FaultOutcome:
    """log: the twin's own record of what it injected (t_s on the twin's clock, as the injector logged it);
    t_offset_s: rig clock - twin clock [s]; safe_ms: per fault start, ms to the first follower hold
    command after it, before the fault ended + REACT_WINDOW_S (None: no hold in that window; the stop's
    hold at the end of the run does not count); stale_ms: per fault start, the age of the oldest sample
    the pair used at that hold (data_age_ms), None without one; recovered: per fault, the pair tracked
    the leader again (coupled or soft start) after the fault ended; violations: commands outside the limits;
    safe_at_end: leader at zero torque and follower holding after the run; jumps_rejected: leader + follower
    samples held as implausible; messages: (t, who, text)."""

    log: list
    t_offset_s: float
    safe_ms: list = field(default_factory=list)
    stale_ms: list = field(default_factory=list)
    recovered: list = field(default_factory=list)
    violations: int = 0
    safe_at_end: bool = False
    jumps_rejected: int = 0
    messages: list = field(default_factory=list)
    ticks: int = 0
    error: str | None = None
    follower_q_sent: np.ndarray | None = None  # (n, joints) follower position commands on the wire [rad]
    follower_t_sent: np.ndarray | None = None  # (n,) when each was issued [s, rig clock]
    follower_q_read: np.ndarray | None = None  # (ticks, joints) the follower positions the pair used [rad]
    device_notes: list = field(default_factory=list)  # the drivers' warnings (a leader servo rebooted, ...)
    recording: RecordingCheck | None = None  # with record_dir: what the file holds against the ticks run
    t_ticks: np.ndarray | None = None  # (ticks,) when each tick ran [s, rig clock]


@dataclass
class RecordingCheck:
    """A fault run's recording against what happened: ticks the loop ran before the first fault started
    (each hands one follower sample to the recorder) and how many of them the file lacks; whether the file
    opens; the recorder's error (disk full) and the notes it holds (camera marks)."""

    path: str
    opens: bool
    error: str | None
    ticks_before_fault: int
    lost_before_fault: int
    samples_recorded: int
    notes: list = field(default_factory=list)


def samples_lost(t_ticks: np.ndarray, t_recorded: np.ndarray, t_before: float) -> tuple[int, int]:
    """(ticks before t_before [s], how many of them have no recorded sample): a tick's sample is recorded
    when a recorded timestamp equals its time (to 1 us; both are the rig clock)."""
    t_ticks = np.asarray(t_ticks, float)
    before = t_ticks[t_ticks < t_before]
    got = np.isin(np.round(before * 1e6), np.round(np.asarray(t_recorded, float) * 1e6))
    return int(len(before)), int((~got).sum())


_NOT_FRESH = STATUS_STALE | STATUS_COMM_LOST


def fresh_times(prev: tuple[float, ...] | None, *states) -> tuple[float, ...]:
    """Each device's newest sample time with every joint fresh [s]: a sample's own t where no joint is
    flagged stale, else the previous value (a partial Dynamixel read is stamped when it was read, its
    unanswered joints flagged; a lost CAN frame leaves the old sample and its old t)."""
    out = []
    for i, st in enumerate(states):
        fresh = not np.any(np.asarray(st.status, np.uint32) & np.uint32(_NOT_FRESH))
        out.append(float(st.t) if fresh or prev is None else prev[i])
    return tuple(out)


def data_age_ms(t_hold: float | None, t_ticks, t_samples) -> float | None:
    """How old the data was when the follower was held [ms]: at the last tick up to t_hold [s], t_hold minus
    the oldest of the devices' newest all-fresh samples at that tick (t_samples: (ticks, devices) [s],
    fresh_times). The reaction a partial fault owes (a burst of loss, a corrupted packet) starts when a
    device's data goes stale, not when the fault starts: one watchdog period from the last fresh sample."""
    if t_hold is None:
        return None
    t_ticks = np.asarray(t_ticks, float)
    k = int(np.searchsorted(t_ticks, t_hold + 1e-9, "right")) - 1
    if k < 0:
        return None
    return float((t_hold - np.min(np.asarray(t_samples, float)[k])) * 1e3)


def check_recording(path, t_ticks, t_fault: float, error: str | None) -> RecordingCheck:
    """Open the recording (without its cache) and count what it lacks before t_fault [s, rig clock]."""
    import warnings

    from hardware.recording.reader import Recording

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a truncated file reads with a warning: counted, not shown
            rec = Recording(path, use_cache=False, write_cache=False)
            t_rec = rec.topic("/follower/joint_state").t
            notes = [e.get("text", "") for e in rec.events if e.get("kind") == "note"]
    except Exception:  # noqa: BLE001 -- a file that does not open is the outcome measured: all lost
        n, _ = samples_lost(t_ticks, [], t_fault)
        return RecordingCheck(str(path), False, error, n, n, 0)
    n, lost = samples_lost(t_ticks, t_rec, t_fault)
    return RecordingCheck(str(path), True, error, n, lost, int(len(t_rec)), notes)


def run_with_faults(specs, seconds: float = 2.5, seed: int = 0, rig: str = "sim-piper", record_dir=None,
                    cameras: bool = False, mode: str = "ground_truth",
                    clock: str = "lockstep") -> FaultOutcome:
    """Run the demo task's teleop (ground-truth feedback) in lockstep while the twin plays `specs`;
    record_dir: record the run there (one episode; cameras: with the rig's cameras) and check the file.
    mode / clock: DemoConfig's (a killed NEXT worker needs "next" on a real-time clock: only there is NEXT a
    process of its own)."""
    next_src, next_path = None, None
    if mode == "next":  # the demo's NEXT (the cache `factr2 demo` makes), as the demo itself runs it
        from factr2_teleop.session.next_cache import find_checkpoint
        from factr2_teleop.session.pairs import load_next
        from hardware.rigs.rig import load_rig

        next_path = find_checkpoint(rig, None)
        if next_path is None:
            raise UserError(f"no NEXT checkpoint for {rig}", where="fault run, mode next",
                            fix=f"run `factr2 demo --rig {rig} --mode next` once (it trains the cache)")
        next_src = load_next(next_path, load_rig(rig).followers[0].arm)
    # a real-time run at the app's own rate (DemoConfig's default), a lockstep one at RATE_HZ
    rate = RATE_HZ if clock == "lockstep" else DemoConfig.rate_hz
    run = DemoRun(DemoConfig(rig=rig, seconds=seconds, mode=mode, clock=clock, rate_hz=rate,
                             seed=seed, faults=tuple(specs)), next_source=next_src,
                  next_path=str(next_path) if next_path else None)
    phases: list[tuple[float, str]] = []
    q_read: list[np.ndarray] = []
    sample_t: list[tuple[float, float]] = []  # (follower, leader) newest all-fresh sample times [s]

    def on_tick(rec) -> None:
        phases.append((rec.t, rec.phase))
        q_read.append(np.array(rec.follower.q, dtype=float))
        sample_t.append(fresh_times(sample_t[-1] if sample_t else None, rec.follower, rec.leader))

    run.teleop.hooks.append(on_tick)
    try:
        twin = run.session.twin
        rec = None
        if record_dir is not None:
            rec = run.teleop.record(record_dir, cameras=cameras)
            rec.start_episode("faults")
        try:
            run.run()
        except Exception as e:  # noqa: BLE001 -- an outcome to count, not a test's traceback
            err = f"{type(e).__name__}: {e}"
        else:
            err = None
        finally:  # (also on SIGTERM's interrupt: the file ends complete, as the app's)
            status = run.teleop.close_recording("fault run ended") if rec is not None else None
        res = run.result()
        out = FaultOutcome(log=list(twin.faults.log) if twin.faults else [],
                           t_offset_s=twin.rig_time() - twin.t,
                           violations=int(res.max_command_violation), ticks=res.ticks, error=err,
                           messages=list(run.loop.snapshot().messages))
    finally:
        run.close()
    tf, qf = run.wire_f.arrays()
    hold = np.array(run.wire_f.hold, dtype=bool)
    _, tau_l = run.wire_l.arrays()
    out.follower_q_sent, out.follower_t_sent, out.follower_q_read = qf, tf, np.array(q_read)
    out.t_ticks = np.array([t for t, _ in phases])
    out.safe_at_end = bool(len(hold) and hold[-1] and len(tau_l) and np.all(tau_l[-1] == 0.0))
    out.jumps_rejected = run.leader.safety.jumps_rejected + run.follower.safety.jumps_rejected
    out.device_notes = [w for d in (run.leader, run.follower) for w in getattr(d, "warnings", [])]
    starts = [e for e in out.log if e["event"] == "start"]
    if rec is not None:
        t_fault = min((e["t_s"] for e in starts), default=np.inf) + out.t_offset_s
        out.recording = check_recording(rec.path, [t for t, _ in phases], t_fault, status.error)
    ends = {e["kind"] + repr(e.get("joint")): e["t_s"] for e in out.log if e["event"] == "end"}
    t_last = phases[-1][0] if phases else -np.inf  # the loop's last tick: the stop's hold comes after it
    for e in starts:
        t0 = e["t_s"] + out.t_offset_s
        t_end = ends.get(e["kind"] + repr(e.get("joint")), e["t_s"]) + out.t_offset_s
        after = tf[hold & (tf >= t0) & (tf <= min(t_end + REACT_WINDOW_S, t_last))]
        out.safe_ms.append(float((after[0] - t0) * 1e3) if len(after) else None)
        out.stale_ms.append(data_age_ms(float(after[0]) if len(after) else None, out.t_ticks, sample_t))
        out.recovered.append(any(t > t_end and p in (COUPLED, SOFT_START) for t, p in phases))
    return out
