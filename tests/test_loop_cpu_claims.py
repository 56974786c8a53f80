"""A pinned real-time loop claims its CPU; the app's background jobs (a training) keep their threads off it,
and a claim whose process died is dropped (hardware/realtime.py)."""

import os
import subprocess
import sys

import pytest

from hardware import realtime as R

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                                reason="needs CPU affinity and two CPUs")


@pytest.fixture(autouse=True)
def _own_claims_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    monkeypatch.delenv("FACTR2_NO_PIN", raising=False)
    monkeypatch.delenv("FACTR2_NO_RT", raising=False)


def test_a_training_keeps_off_the_claimed_cpu_and_back_when_released():
    cpus = set(os.sched_getaffinity(0))
    loop_cpu = max(cpus)
    keep = R.KeepOffLoopCpus(every_s=0.0)
    try:
        claim = R.claim_loop_cpu(loop_cpu)
        assert R.claimed_loop_cpus() == {loop_cpu}
        assert keep.refresh(1.0) == cpus - {loop_cpu}
        assert set(os.sched_getaffinity(0)) == cpus - {loop_cpu}  # this thread moved, as every other
        R.release_loop_cpu(claim)
        assert keep.refresh(2.0) == cpus and set(os.sched_getaffinity(0)) == cpus
    finally:
        os.sched_setaffinity(0, cpus)


def test_every_cpu_claimed_leaves_the_job_all_of_them():
    before = set(os.sched_getaffinity(0))
    cpus = set(sorted(before)[:2])  # two CPUs, each claimed by a live process: this one and its parent
    d = R._claims_dir()
    d.mkdir(parents=True)
    try:
        os.sched_setaffinity(0, cpus)
        for pid, c in zip((os.getpid(), os.getppid()), sorted(cpus)):
            (d / str(pid)).write_text(str(c))
        assert R.KeepOffLoopCpus(every_s=0.0).refresh(1.0) == cpus
    finally:
        os.sched_setaffinity(0, before)


def test_a_dead_loops_claim_is_dropped():
    p = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                       capture_output=True, text=True)
    dead = int(p.stdout)
    R.claim_loop_cpu(0).rename(R._claims_dir() / str(dead))
    assert R.claimed_loop_cpus() == set()
    assert not (R._claims_dir() / str(dead)).exists()


def test_loop_cpu_claims_while_pinned_and_releases():
    pin = R.LoopCpu()
    pin.start()
    try:
        assert pin.note is None and R.claimed_loop_cpus() == {pin.cpu}
    finally:
        pin.restore()
    assert R.claimed_loop_cpus() == set()
