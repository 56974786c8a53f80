"""NEXT in its own process (issue #24): the control loop posts each model sample and picks estimates up
without waiting, so the LSTM's arithmetic (~0.1 ms per 2 ms tick on a 2-vCPU VM, the largest single share
of the loop's own CPU) runs on another core instead of inside the loop's period.

    est = NextWorker(checkpoint_path, arm, n_joints, loop_period_s, rate_hz)   # starts it, returns at once
    est.update(inp) / est.refresh(inp) / est.idle()                   # calibration.estimators protocol
    est.close()

What changes against NextAdapter on the loop's thread: an estimate arrives about one control tick after
its sample (the worker answers while the loop sleeps), and between model samples refresh() still gives
tau_m(now) - tau_f of the newest prediction, so contact shows in the feedback at once. Only real-time
clocks use it (factr2_teleop.session.pairs): lockstep runs keep NEXT inline, where the tick order is the
determinism (issue #24 item 4). The child builds the same NextEstimator from the checkpoint file (not
pickled: its LSTM state shares memory between numpy and torch), in a fresh interpreter started with
`python -m calibration.next.worker` over a socket pair -- not multiprocessing's spawn, which re-imports the
caller's __main__ (a script without a main guard, stdin, a notebook).

Failure is loud and safe: a worker that dies, or falls MAX_IN_FLIGHT samples behind, raises in update();
the pair then turns feedback off with a message (factr2_teleop.teleop.pair). A worker that died is started
again (RESTARTS_MAX times): feedback comes back, said by the pair, once the new one is ready and warm.
Messages are raw float64 rows (no pickling per sample): ~3 us per tick on the loop's side.
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import time
import weakref
from multiprocessing.connection import Connection

import numpy as np

from calibration.estimate import Estimate
from calibration.estimators import Estimator, EstimatorInput, NextAdapter, next_period_s, refresh_with
from hardware.realtime import ESTIMATOR_PRIORITY, spawn_normal
from hardware.types import JointState

READY_TIMEOUT_S = 60.0  # s: the child imports torch and loads the checkpoint (2-5 s on a 2-vCPU VM)
MAX_IN_FLIGHT = 25  # samples posted and not answered (0.25 s at 100 Hz): the worker cannot keep up
RESTARTS_MAX = 3  # restarts of a worker that died, while the rig is open (then feedback stays off)


# -- wire format (pure) ------------------------------------------------------------------------------
def pack_sample(inp: EstimatorInput) -> bytes:
    """[t, follower t, has target, q, q_dot, q_cmd, tau_m, temperature, q_target] as float64 bytes."""
    st, tgt = inp.follower, inp.q_target_f
    n = len(st.q)
    return np.concatenate(([inp.t, st.t, 0.0 if tgt is None else 1.0], st.q, st.q_dot, st.q_cmd, st.tau_m,
                           st.temperature, np.full(n, np.nan) if tgt is None else tgt)).tobytes()


def unpack_sample(buf: bytes, n: int) -> EstimatorInput:
    a = np.frombuffer(buf, np.float64)
    v = [a[3 + k * n: 3 + (k + 1) * n].copy() for k in range(6)]
    st = JointState(t=float(a[1]), q=v[0], q_dot=v[1], q_cmd=v[2], tau_m=v[3], current=np.full(n, np.nan),
                    temperature=v[4], status=np.zeros(n, np.uint32))
    return EstimatorInput(t=float(a[0]), follower=st, q_leader_f=np.full(n, np.nan),
                          q_target_f=v[5] if a[2] else None)


def pack_result(e: Estimate | None, ood_count: int, cpu_s: float, n: int) -> bytes:
    """[has estimate, t, flags, ood count, worker CPU s, tau_ext, tau_f (NaN: none), has tau_f]."""
    if e is None:
        return np.concatenate(([0.0, np.nan, 0.0, ood_count, cpu_s], np.full(2 * n + 1, np.nan))).tobytes()
    tau_f = e.tau_f
    return np.concatenate(([1.0, e.t, float(e.flags), ood_count, cpu_s], e.tau_ext,
                           np.full(n, np.nan) if tau_f is None else tau_f,
                           [0.0 if tau_f is None else 1.0])).tobytes()


def unpack_result(buf: bytes, n: int) -> tuple[Estimate | None, int, float]:
    """(estimate or None while warming up, ood count, worker CPU [s])."""
    a = np.frombuffer(buf, np.float64)
    ood, cpu = int(a[3]), float(a[4])
    if not a[0]:
        return None, ood, cpu
    tau_f = a[5 + n: 5 + 2 * n].copy() if a[5 + 2 * n] else None
    return Estimate(tau_ext=a[5: 5 + n].copy(), t=float(a[1]), flags=int(a[2]), tau_f=tau_f), ood, cpu


# -- the child -------------------------------------------------------------------------------------
def _serve(conn, path: str, arm: str, n: int, loop_period_s: float) -> None:
    """Build NEXT from the checkpoint, answer every sample with the estimate of it, until the pipe closes."""
    from hardware.threads import limit_threads

    with limit_threads(1, torch=True):  # one core for the worker: the loop and its twin have the others
        _load_and_answer(conn, path, arm, n, loop_period_s)


def _load_and_answer(conn, path: str, arm: str, n: int, loop_period_s: float) -> None:
    try:
        from calibration.next.checkpoint import load_checkpoint
        from calibration.next.estimator import NextEstimator

        adapter = NextAdapter(NextEstimator(load_checkpoint(path, arm=arm)), loop_period_s)
    except Exception as e:  # noqa: BLE001 -- reported to the parent as one line
        conn.send(("error", f"{type(e).__name__}: {e}"))
        return
    conn.send(("ready", adapter.period_s))
    c0 = time.process_time()  # the CPU it spends answering, not loading
    while True:
        try:
            buf = conn.recv_bytes()
        except (EOFError, OSError):
            return  # the loop closed the pipe or its process ended
        est = adapter.update(unpack_sample(buf, n))
        try:
            conn.send_bytes(pack_result(est, adapter.ood_count, time.process_time() - c0, n))
        except OSError:  # the loop closed the pipe meanwhile (it stopped, or gave up on us): done, quietly
            return


# -- the loop's side ---------------------------------------------------------------------------------
class NextWorker(Estimator):
    """calibration.estimators.NextAdapter's behaviour with NEXT in a child process (module docstring)."""

    def __init__(self, path: str, arm: str, n: int, loop_period_s: float = 0.0, rate_hz: float = 0.0,
                 ready_timeout_s: float = READY_TIMEOUT_S):
        """Starts the child and returns at once (the loop does not wait ~2-5 s for it, while a leader
        without torque sags): until it is ready, update() gives no estimate (NEXT warms up anyway). rate_hz:
        the checkpoint's sample rate (period_s, as NextAdapter)."""
        self.n = n
        self.period_s = next_period_s(rate_hz, loop_period_s)
        self._path, self._timeout_s = str(path), ready_timeout_s
        self._args = (str(path), arm, str(n), repr(float(loop_period_s)))
        self.restarts = 0  # times a dead worker was started again (RESTARTS_MAX at most)
        self._spawn()
        self.ood_count = 0
        self.flags = 0
        self.cpu_s = 0.0  # CPU time [s] the worker spent answering samples so far
        self.in_flight = 0  # samples posted and not yet answered
        self._posted: list[float] = []  # monotonic time each unanswered sample was posted [s]
        self.answers = 0
        self.answer_delay_sum_s = self.answer_delay_max_s = 0.0  # post -> picked up by the loop [s]
        self._held: Estimate | None = None  # newest estimate not yet handed to the loop
        self._tau_f: np.ndarray | None = None

    def _spawn(self) -> None:
        """Start the child (a fresh interpreter: no inherited threads, locks or twin state); not ready yet."""
        self._deadline = time.monotonic() + self._timeout_s
        ours, theirs = socket.socketpair()
        # at normal priority even when a restart starts it from the real-time loop's thread
        self._proc = spawn_normal(
            [sys.executable, "-m", "calibration.next.worker", "--fd", str(theirs.fileno()), *self._args],
            pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL)
        theirs.close()
        self._conn = Connection(ours.detach())
        self._finalizer = weakref.finalize(self, _stop, self._conn, self._proc)
        self.ready = False

    def _died(self, why: str) -> RuntimeError:
        """The worker stopped: start a new one (its estimates come once it is ready, after NEXT's warm-up),
        up to RESTARTS_MAX times; the error to raise (the pair turns feedback off and says it)."""
        self.in_flight, self._posted, self._held, self._tau_f = 0, [], None, None
        self._finalizer()
        if self.restarts >= RESTARTS_MAX:
            return RuntimeError(f"the NEXT worker process stopped ({why}); not restarted again "
                                f"({RESTARTS_MAX} restarts)")
        self.restarts += 1
        self._spawn()
        return RuntimeError(f"the NEXT worker process stopped ({why}); restarting it")

    @classmethod
    def of(cls, next_est, n: int, loop_period_s: float) -> NextWorker:
        """The worker for a NextEstimator loaded here by factr2_teleop.session.pairs.load_next (its `source`:
        checkpoint path and arm); `next` keeps that estimator for its checkpoint's metadata (not stepped)."""
        worker = cls(*next_est.source, n, loop_period_s=loop_period_s, rate_hz=next_est.ck.rate_hz)
        worker.next = next_est
        return worker

    def _check_ready(self, wait_s: float = 0.0) -> bool:
        """True once the child said it is ready; raises (feedback off, with why) when it failed or did not
        answer within ready_timeout_s."""
        if self.ready:
            return True
        try:
            if not self._conn.poll(wait_s):
                if time.monotonic() > self._deadline:
                    raise RuntimeError(f"the NEXT worker did not start in {self._timeout_s:.0f} s")
                return False
            kind, value = self._conn.recv()
        except (EOFError, OSError):  # killed while it loaded (the OOM killer, a user): start it again
            raise self._died(f"it ended while loading, exit code {self._proc.poll()}") from None
        if kind != "ready":  # it said why it cannot load: a new one would not either
            raise RuntimeError(f"the NEXT worker could not load {self._path}: {value}")
        self.ready = True
        return True

    def helper_processes(self) -> dict[int, int]:
        """The child, raised with the loop's threads while a real-time loop runs (hardware.realtime) -- once
        ready: its start-up (importing torch) must not run at a real-time priority; none once closed."""
        return {self._proc.pid: ESTIMATOR_PRIORITY} if self.ready and self._finalizer.alive else {}

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Block until the child is ready (tests, benchmarks); raises as _check_ready."""
        t_end = time.monotonic() + timeout_s
        while not self._check_ready(min(0.1, max(t_end - time.monotonic(), 0.0))):
            if time.monotonic() > t_end:
                raise RuntimeError(f"the NEXT worker did not start in {timeout_s:.0f} s")

    def _take(self) -> None:
        """Read every answer waiting, keep the newest estimate (raises when the worker died)."""
        conn = self._conn
        try:
            while self.in_flight and conn.poll(0):
                est, self.ood_count, self.cpu_s = unpack_result(conn.recv_bytes(), self.n)
                self.in_flight -= 1
                delay = time.monotonic() - self._posted.pop(0)
                self.answers += 1
                self.answer_delay_sum_s += delay
                self.answer_delay_max_s = max(self.answer_delay_max_s, delay)
                if est is None:  # warming up (or restarting after a bad sample): no estimate yet
                    self._tau_f, self._held = None, None
                    continue
                self.flags = est.flags
                self._tau_f = est.tau_f if est.valid else None
                self._held = est
        except (EOFError, OSError) as e:  # a child that ended closed its end (no waitpid per tick needed)
            raise self._died(f"{type(e).__name__}, exit code {self._proc.poll()}") from None

    def _give(self) -> Estimate | None:
        est, self._held = self._held, None
        return est

    def update(self, inp: EstimatorInput) -> Estimate | None:
        if not self._check_ready():
            return None  # still starting: no estimate yet (the sample is not needed: NEXT warms up after)
        if self.in_flight >= MAX_IN_FLIGHT:
            raise RuntimeError(f"the NEXT worker is {self.in_flight} samples behind: it cannot keep up")
        try:
            self._conn.send_bytes(pack_sample(inp))
        except (BrokenPipeError, OSError) as e:
            raise self._died(type(e).__name__) from None
        self.in_flight += 1
        self._posted.append(time.monotonic())
        self._take()
        return self._give()

    def refresh(self, inp: EstimatorInput) -> Estimate | None:
        """A new estimate when one arrived, else this tick's tau_m - the newest predicted free torque (as
        NextAdapter.refresh)."""
        self._take()
        new = self._give()
        if new is not None:
            return new
        return refresh_with(self._tau_f, inp.follower)

    def idle(self) -> None:
        self._take()

    def close(self) -> None:
        self._finalizer()


def _stop(conn, proc) -> None:
    try:
        conn.close()  # the child's recv ends with EOFError and it returns
    finally:
        try:
            proc.wait(1.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(1.0)


def main(argv: list[str] | None = None) -> None:
    """The child: `python -m calibration.next.worker --fd FD CHECKPOINT ARM N LOOP_PERIOD_S`."""
    ap = argparse.ArgumentParser(description="NEXT estimator worker (started by NextWorker)")
    ap.add_argument("--fd", type=int, required=True)
    ap.add_argument("path")
    ap.add_argument("arm")
    ap.add_argument("n", type=int)
    ap.add_argument("loop_period_s", type=float)
    a = ap.parse_args(argv)
    _serve(Connection(a.fd), a.path, a.arm, a.n, a.loop_period_s)


if __name__ == "__main__":
    main()
