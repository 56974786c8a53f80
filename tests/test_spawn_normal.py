"""hardware.realtime.spawn_normal: a process started from a real-time, pinned thread (the control loop's,
when a NEXT worker is restarted mid-session) runs at normal priority on every CPU of the process."""

import os
import subprocess
import sys
import threading

import pytest

from hardware.realtime import LOOP_PRIORITY, PROCESS_CPUS, set_fifo, set_normal, spawn_normal

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="Linux scheduling only")

CHILD = [sys.executable, "-c", "import sys; sys.stdin.read()"]  # lives until its stdin closes


def _from_thread(realtime: bool, pin: bool) -> dict:
    box: dict = {}

    def run() -> None:
        try:
            if realtime and set_fifo(LOOP_PRIORITY) is not None:
                box["skip"] = "SCHED_FIFO not permitted here"
                return
            if pin:
                os.sched_setaffinity(0, {max(PROCESS_CPUS)})
            box["inherits"] = subprocess.Popen(CHILD, stdin=subprocess.PIPE)  # what a plain Popen gives
            box["spawned"] = spawn_normal(CHILD, stdin=subprocess.PIPE)
        finally:
            set_normal()

    th = threading.Thread(target=run)
    th.start()
    th.join()
    if "skip" in box:
        pytest.skip(box["skip"])
    return box


def _close(*procs) -> None:
    for p in procs:
        p.stdin.close()
        p.wait(10)


def test_a_child_of_a_fifo_pinned_thread_runs_normal_on_every_cpu():
    if len(PROCESS_CPUS) < 2:
        pytest.skip("one CPU: nothing to pin away from")
    box = _from_thread(realtime=True, pin=True)
    plain, ours = box["inherits"], box["spawned"]
    try:
        # the premise: a plain Popen inherits both (else this test shows nothing)
        assert os.sched_getscheduler(plain.pid) == os.SCHED_FIFO
        assert os.sched_getaffinity(plain.pid) == {max(PROCESS_CPUS)}
        assert os.sched_getscheduler(ours.pid) == os.SCHED_OTHER
        assert os.sched_getaffinity(ours.pid) == set(PROCESS_CPUS)
    finally:
        _close(plain, ours)


def test_from_a_normal_thread_it_is_a_plain_popen_and_errors_reach_the_caller():
    box = _from_thread(realtime=False, pin=False)
    _close(box["inherits"], box["spawned"])
    assert box["spawned"].returncode == 0

    def run() -> None:  # a pinned thread takes the helper-thread path; pinning needs no privilege
        os.sched_setaffinity(0, {max(PROCESS_CPUS)})
        try:
            spawn_normal(["/nonexistent/factr2-binary"])
        except FileNotFoundError:
            box["raised"] = True

    if len(PROCESS_CPUS) < 2:
        pytest.skip("one CPU: no pinned thread to start from")
    th = threading.Thread(target=run)
    th.start()
    th.join()
    assert box.get("raised")
