"""SIMULATED faults of the app's process and machine (hardware/sim/process_faults.py), seeded: the wall clock
stepping, the recording disk filling (a tmpfs the test mounts), the NEXT worker killed, SIGTERM and SIGKILL
of the app (subprocess runs of `factr2 collect`)."""

from __future__ import annotations

import inspect
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from factr2_teleop.demo.fault_run import run_with_faults, samples_lost
from hardware.recording import Recorder
from hardware.sim.faults import WALL_STEP_S, parse_fault
from tests.fault_helpers import run_fault, said

REPO = Path(__file__).resolve().parents[1]
# s: the recorder's flush interval (its default): what a SIGKILL of app and writer may lose at most
FLUSH_S = inspect.signature(Recorder).parameters["flush_interval_s"].default


def _faults(*texts):
    return [parse_fault(t) for t in texts]


def test_wall_clock_steps_change_nothing_the_loop_or_the_recording_does(tmp_path):
    real = time.time
    base = run_with_faults([], seconds=1.5, record_dir=tmp_path / "a")
    out = run_with_faults(_faults("wall_step_fwd@0.5", "wall_step_back@1.0"), seconds=1.5,
                          record_dir=tmp_path / "b")
    assert out.error is None and out.violations == 0 and out.safe_at_end
    assert [e["detail"] for e in out.log if e["event"] == "start"] == [f"wall clock {WALL_STEP_S:+g} s",
                                                                        f"wall clock {-WALL_STEP_S:+g} s"]
    np.testing.assert_array_equal(out.follower_q_sent, base.follower_q_sent)  # bit for bit
    np.testing.assert_array_equal(out.t_ticks, base.t_ticks)
    from hardware.recording.reader import Recording

    t_rec = Recording(out.recording.path, use_cache=False, write_cache=False).topic("/follower/joint_state").t
    assert samples_lost(out.t_ticks, t_rec, np.inf) == (len(out.t_ticks), 0)  # every tick, at its time
    assert np.all(np.diff(t_rec) > 0)
    assert time.time is real  # the twin's close undid the step


@pytest.fixture()
def small_fs(tmp_path):
    """A 4 MiB tmpfs the test mounts (root with CAP_SYS_ADMIN). Without it this test is skipped; the
    recorder's size-limited writer (EFBIG at RLIMIT_FSIZE) is covered by tests/test_recording_crash.py."""
    d = tmp_path / "fs"
    d.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(d)], capture_output=True,
                       text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip() or r.returncode})")
    yield d
    subprocess.run(["umount", "-l", str(d)], check=False)


def test_disk_full_stops_the_recording_said_teleop_goes_on_and_the_file_opens(small_fs):
    out = run_fault("disk_full@1.0:0.5", seconds=2.0)  # nothing records here: not played
    assert out.log[0]["played"] is False and "nothing records" in out.log[0]["detail"]
    out = run_with_faults(_faults("disk_full@1.0:1.5"), seconds=3.0, record_dir=small_fs)
    assert out.error is None and out.violations == 0 and out.safe_at_end
    assert out.log[0]["played"] and out.log[0]["detail"].startswith("filled")
    rc = out.recording
    assert rc.opens and rc.error and "the disk is full" in rc.error and "the file is complete" in rc.error
    # said while teleop runs; or, when the writer reported after the loop's last health check (a writer
    # starved by other work on the machine: seen in CI beside a training), as the recording closed
    assert said(out, "teleop goes on without recording") or said(out, "found as the recording closed")
    assert out.ticks == len(out.t_ticks) and out.t_ticks[-1] > 2.9  # the session ran to its end
    # everything handed over before the disk filled is in the file (the writer's space reserve took it)
    assert rc.samples_recorded >= rc.ticks_before_fault > 0 and rc.lost_before_fault == 0, rc
    assert not list(small_fs.glob(".*.reserve"))
    assert not list(small_fs.glob(".factr2-fault-disk-full"))  # the filler went with the twin


def test_disk_full_behind_a_stalled_writer_keeps_everything_handed_over_before(small_fs):
    """A lockstep loop runs ahead of its writer: the disk fills while the writer is seconds behind (stopped
    here with SIGSTOP). Everything handed over before the fill is in the file (the reserve takes it); what
    comes after is refused and counted."""
    import signal

    from hardware.recording.reader import Recording
    from hardware.sim.process_faults import fill_disk, free_disk
    from hardware.types import JointState

    def js(t):
        z = np.zeros(6)
        return JointState(t=t, q=z + t, q_dot=z, tau_m=z, current=z, q_cmd=z, temperature=z,
                          status=np.zeros(6, np.uint32))

    rec = Recorder(small_fs / "s.mcap", joint_names={"follower": [f"j{i}" for i in range(6)]}, t0=0.0,
                   lossless=True)
    rec.start_episode(0.0, "fill")
    for k in range(500):
        rec.log_joint_state("follower", k * 0.002, js(k * 0.002))
    deadline = time.monotonic() + 20
    while rec.status().messages_written < 500 and time.monotonic() < deadline:  # the writer is running
        time.sleep(0.01)
    os.kill(rec._proc.pid, signal.SIGSTOP)  # the writer falls behind: everything below waits in the ring
    try:
        for k in range(500, 1500):
            rec.log_joint_state("follower", k * 0.002, js(k * 0.002))
        assert fill_disk(small_fs).startswith("filled")
    finally:
        os.kill(rec._proc.pid, signal.SIGCONT)
    deadline = time.monotonic() + 20
    while rec.status().recording and time.monotonic() < deadline:  # refused once the writer sees the fill
        time.sleep(0.01)
    after = [rec.log_joint_state("follower", 3.0 + k * 0.002, js(3.0)) for k in range(10)]
    st = rec.close()
    free_disk(small_fs)
    assert not any(after) and st.error and "the disk is full" in st.error, st
    t = Recording(small_fs / "s.mcap", use_cache=False, write_cache=False).topic("/follower/joint_state").t
    assert len(t) == 1500 and np.all(np.diff(t) > 0)


def test_killed_next_worker_is_restarted_and_estimates_come_back(tmp_path):
    from calibration.next.checkpoint import save_checkpoint
    from calibration.next.worker import NextWorker
    from hardware.sim.process_faults import kill_next_workers
    from tests.test_next_estimator import _ck
    from tests.test_next_worker import _answer, _inputs

    path = save_checkpoint(_ck(history=12, n_j=3), tmp_path / "next")
    w = NextWorker(path, "test", 3, 0.002)
    try:
        w.wait_ready()
        inputs = _inputs(200)
        for x in inputs[:40]:
            w.update(x)
            _answer(w)
        assert w.answers == 40
        assert kill_next_workers().startswith("killed NEXT worker pid")
        with pytest.raises(RuntimeError, match="restarting it"):
            for x in inputs[40:80]:
                w.update(x)
                time.sleep(0.01)
        assert w.restarts == 1
        w.wait_ready()
        est = []
        for x in inputs[80:]:
            est.append(w.update(x))
            _answer(w)
            est.append(w.refresh(x))
        assert any(e is not None and e.valid for e in est)  # feedback comes back (warm again)
    finally:
        w.close()
    assert kill_next_workers() == "not played: no NEXT worker"


def test_next_worker_killed_while_it_loads_is_started_again(tmp_path):
    """Killed before it said ready (a real-time session's first seconds, when the worker imports torch):
    the same restart as a worker killed later, not a load failure that keeps feedback off for the session."""
    from calibration.next.checkpoint import save_checkpoint
    from calibration.next.worker import NextWorker
    from hardware.sim.process_faults import kill_next_workers
    from tests.test_next_estimator import _ck

    path = save_checkpoint(_ck(history=12, n_j=3), tmp_path / "next")
    w = NextWorker(path, "test", 3, 0.002)
    try:
        assert kill_next_workers().startswith("killed NEXT worker pid")  # at once: it is still loading
        with pytest.raises(RuntimeError, match="ended while loading.*restarting it"):
            w.wait_ready()
        assert w.restarts == 1
        w.wait_ready()  # the new one loads
        assert w.ready
    finally:
        w.close()


def _collect(out: Path, fault: str):
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "factr2_teleop.cli", "collect", "--task", "peg-insert",
                           "--episodes", "1", "--out", str(out), "--mode", "dob", "--no-cameras",
                           "--twin-fault", fault], capture_output=True, text=True, env=env, timeout=300)


def _follower_times(out: Path):
    from hardware.recording.reader import open_when_finished

    (path,) = out.glob("*.mcap")
    rec = open_when_finished(path, wait_s=60.0)  # after a SIGKILL its writer is still draining
    assert not rec.truncated, "the writer process did not finish the file"
    return rec, rec.topic("/follower/joint_state").t


@pytest.mark.parametrize("sig", ["sigterm", "sigkill"])
def test_app_signal_ends_safely_and_the_recording_opens(tmp_path, sig):
    r = _collect(tmp_path, f"app_{sig}@2.0")
    assert "Traceback" not in r.stderr
    rec, t = _follower_times(tmp_path)
    assert len(t) and np.all(np.diff(t) > 0)
    if sig == "sigterm":  # Ctrl-C's path: the arms made safe, the episode closed with a note
        assert r.returncode == 143 and "terminated (SIGTERM): stopped safely" in r.stderr
        assert any(e["kind"] == "note" and "interrupted" in e["text"] for e in rec.events)
    else:  # nothing of the app ran: its writer process finished the file
        assert r.returncode == -9
    assert t[-1] >= 2.0 - FLUSH_S  # at most the last flush interval lost (lockstep: sim time ~ wall time)


def test_a_write_that_finds_the_disk_full_takes_the_reserve_and_goes_on(small_fs):
    """The race the campaign found: the disk fills between the writer's look at the free space and its write.
    The write gives the reserve back and goes on; without a reserve, ENOSPC is raised as before."""
    import errno

    from hardware.recording.space import ReserveBackedFile, SpaceReserve
    from hardware.sim.process_faults import fill_disk, free_disk

    path = small_fs / "r.bin"
    reserve = SpaceReserve(path)
    assert reserve.size > 0
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o644)
    raw = ReserveBackedFile(fd, reserve)
    try:
        assert fill_disk(small_fs).startswith("filled")
        data = b"x" * 65536
        assert raw.write(data) == len(data) and raw.full.is_set() and reserve.size == 0
        with pytest.raises(OSError) as e:
            while True:  # the reserve is spent: the disk is full again
                raw.write(data)
        assert e.value.errno == errno.ENOSPC
    finally:
        raw.close()
        free_disk(small_fs)


def test_a_disk_full_that_took_the_reserve_too_is_said_as_the_disk_full():
    """Whichever write meets ENOSPC first, the line says the disk is full, what was kept and what to do."""
    import errno

    from hardware.recording.writer_process import fail_text

    text = fail_text("/x/r.mcap", OSError(errno.ENOSPC, "No space left on device"))
    assert "the disk is full" in text and "factr2 recover /x/r.mcap" in text and "\n" not in text
    other = fail_text("/x/r.mcap", OSError(errno.EIO, "Input/output error"))
    assert "Input/output error" in other and "the disk is full" not in other
