"""NEXT in its own process (calibration/next/worker.py): the wire format round-trips, the worker's estimates
equal NextAdapter's on the loop's thread, and a dead or missing worker is an error, never a silent stop."""

from __future__ import annotations

import time

import numpy as np
import pytest
from machine_speed import budget

from calibration.estimate import Estimate
from calibration.estimators import EstimatorInput, NextAdapter
from calibration.next.checkpoint import save_checkpoint
from calibration.next.estimator import NextEstimator
from calibration.next.worker import NextWorker, pack_result, pack_sample, unpack_result, unpack_sample
from hardware.realtime import ESTIMATOR_PRIORITY
from hardware.types import JointState
from tests.test_next_estimator import _ck, _stream

N = 3


def _inputs(n=40):
    q, qd, qc, tau = _stream(n, N)
    out = []
    for i in range(n):
        st = JointState(t=0.01 * i, q=q[i], q_dot=qd[i], tau_m=tau[i], current=np.full(N, np.nan),
                        q_cmd=qc[i] if i % 7 else np.full(N, np.nan), temperature=np.full(N, 30.0),
                        status=np.zeros(N, np.uint32))
        out.append(EstimatorInput(t=0.01 * i + 0.001, follower=st, q_leader_f=q[i],
                                  q_target_f=None if i % 5 == 0 else qc[i] + 0.01))
    return out


def test_wire_format_round_trips():
    for inp in _inputs(6):
        back = unpack_sample(pack_sample(inp), N)
        assert back.t == inp.t and back.follower.t == inp.follower.t
        for f in ("q", "q_dot", "q_cmd", "tau_m", "temperature"):
            np.testing.assert_array_equal(getattr(back.follower, f), getattr(inp.follower, f))
        assert (back.q_target_f is None) == (inp.q_target_f is None)
    e = Estimate(tau_ext=np.array([1.0, -2.0, 3.0]), t=0.5, flags=4, tau_f=np.array([0.1, 0.2, 0.3]))
    got, ood, cpu = unpack_result(pack_result(e, 7, 1.5, N), N)
    assert (ood, cpu, got.t, got.flags) == (7, 1.5, 0.5, 4)
    np.testing.assert_array_equal(got.tau_f, e.tau_f)
    assert unpack_result(pack_result(None, 0, 0.0, N), N)[0] is None
    assert unpack_result(pack_result(Estimate(np.zeros(N)), 0, 0.0, N), N)[0].tau_f is None


def _answer(worker: NextWorker, timeout_s: float = 10.0) -> None:
    t_end = time.monotonic() + budget(timeout_s)  # sized on the dev VM (#53)
    while worker.in_flight and time.monotonic() < t_end:
        worker.idle()
        time.sleep(0.001)
    assert worker.in_flight == 0


def test_worker_estimates_equal_the_inline_adapter(tmp_path):
    path = save_checkpoint(_ck(history=12, n_j=N), tmp_path / "next")
    inline = NextAdapter(NextEstimator(_ck(history=12, n_j=N)), 0.002)
    worker = NextWorker(str(path), "test", N, 0.002, rate_hz=100.0)
    try:
        assert worker.update(_inputs(1)[0]) is None or worker.ready  # returns at once while it starts
        worker.wait_ready()
        assert worker.period_s == inline.period_s
        # the loop that holds this estimator raises its child with its threads (hardware.realtime)
        assert worker.helper_processes() == {worker._proc.pid: ESTIMATOR_PRIORITY}
        n_est = 0
        for inp in _inputs():
            want = inline.update(inp)
            got = worker.update(inp)  # the answer to this sample usually comes in a later call
            _answer(worker)
            got = got or worker._give()
            assert (got is None) == (want is None)
            if want is not None:
                n_est += 1
                np.testing.assert_array_equal(got.tau_ext, want.tau_ext)
                np.testing.assert_array_equal(got.tau_f, want.tau_f)
                assert (got.t, got.flags) == (want.t, want.flags)
                # between samples: this tick's tau_m minus the newest prediction, as inline
                later = EstimatorInput(inp.t + 0.002, JointState(**{**inp.follower.__dict__,
                                                                     "tau_m": inp.follower.tau_m + 1.0}),
                                       inp.q_leader_f)
                np.testing.assert_array_equal(worker.refresh(later).tau_ext, inline.refresh(later).tau_ext)
        assert n_est > 10 and worker.ood_count == inline.ood_count and worker.cpu_s > 0
    finally:
        worker.close()
    assert worker._proc.poll() is not None and worker.helper_processes() == {}


def test_a_dead_worker_raises_and_a_failed_start_says_why(tmp_path):
    bad = NextWorker(str(tmp_path / "none.json"), "test", N)
    with pytest.raises(RuntimeError, match="could not load .*none.json"):
        bad.wait_ready(30.0)
    bad.close()
    path = save_checkpoint(_ck(history=12, n_j=N), tmp_path / "next")
    worker = NextWorker(str(path), "test", N)
    worker.wait_ready()
    worker._proc.kill()
    worker._proc.wait(5)
    inp = _inputs(2)[0]
    with pytest.raises(RuntimeError, match="NEXT worker"):
        for _ in range(3):
            worker.update(inp)
            time.sleep(0.05)
    worker.close()
