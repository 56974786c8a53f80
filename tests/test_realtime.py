"""hardware.realtime: SCHED_FIFO where allowed, one line why not, and the thread given back."""

import os
import threading

import pytest

from hardware.realtime import LOOP_PRIORITY, RtRefusal, set_fifo, set_normal

linux = pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="no POSIX scheduling here")


@linux
def test_fifo_is_set_and_given_back_or_said_why(monkeypatch):
    monkeypatch.delenv("FACTR2_NO_RT", raising=False)
    out = {}

    def body():
        tid = threading.get_native_id()
        out["why"] = set_fifo(LOOP_PRIORITY)
        out["during"] = os.sched_getscheduler(tid)
        set_normal()
        out["after"] = os.sched_getscheduler(tid)

    th = threading.Thread(target=body)
    th.start()
    th.join()
    if out["why"] is None:
        assert out["during"] == os.SCHED_FIFO
    else:  # not permitted here: one line, and the thread was left as it was
        assert out["why"].kind in (RtRefusal.NOT_PERMITTED, RtRefusal.REFUSED, RtRefusal.UNAVAILABLE)
        assert "\n" not in str(out["why"]) and "normal priority" in str(out["why"])
        assert out["during"] == os.SCHED_OTHER
    assert out["after"] == os.SCHED_OTHER


def test_switched_off_by_environment(monkeypatch):
    monkeypatch.setenv("FACTR2_NO_RT", "1")
    why = set_fifo(LOOP_PRIORITY)
    assert why is not None and why.kind is RtRefusal.OFF and "FACTR2_NO_RT" in str(why)


@linux
def test_process_threads_are_raised_below_the_loop_and_given_back(monkeypatch):
    from hardware.realtime import ProcessThreads

    monkeypatch.delenv("FACTR2_NO_RT", raising=False)
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, daemon=True)
    other.start()
    pt = ProcessThreads(priority=5)
    try:
        pt.refresh()
        policy = os.sched_getscheduler(other.native_id)
        if pt.note is None:  # permitted here: raised, and given back by restore()
            assert policy == os.SCHED_FIFO and os.sched_getparam(other.native_id).sched_priority == 5
            assert os.sched_getscheduler(threading.get_native_id()) == os.SCHED_OTHER  # the caller untouched
        else:
            assert policy == os.SCHED_OTHER
    finally:
        pt.restore()
        assert os.sched_getscheduler(other.native_id) == os.SCHED_OTHER
        stop.set()
        other.join()


def test_cpu_wake_latency_request_is_held_while_open(tmp_path, monkeypatch):
    import struct

    from hardware.realtime import CpuWakeLatency

    monkeypatch.delenv("FACTR2_NO_RT", raising=False)
    dev = tmp_path / "cpu_dma_latency"  # stands in for the PM QoS device: what is written, and when
    dev.write_bytes(b"")
    req = CpuWakeLatency(str(dev))
    assert req.active and req.note is None
    assert struct.unpack("i", dev.read_bytes()) == (0,)  # 0 us allowed
    req.close()
    assert not req.active
    gone = CpuWakeLatency(str(tmp_path / "absent"))  # no PM QoS here: nothing to ask, nothing said
    assert not gone.active and gone.note is None
    monkeypatch.setenv("FACTR2_NO_RT", "1")
    off = CpuWakeLatency(str(dev))
    assert not off.active and "FACTR2_NO_RT" in off.note


@linux
def test_loop_cpu_pins_the_loop_alone_and_gives_everything_back(monkeypatch):
    from hardware.realtime import LoopCpu

    monkeypatch.delenv("FACTR2_NO_RT", raising=False)
    allowed = set(os.sched_getaffinity(0))
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, daemon=True)
    other.start()
    pin = LoopCpu()
    try:
        pin.start()
        if len(allowed) < 2:
            assert pin.note and pin.cpu is None
        else:
            assert pin.note is None and pin.cpu == max(allowed)
            assert os.sched_getaffinity(0) == {pin.cpu}  # the caller: the loop's thread, alone
            assert os.sched_getaffinity(other.native_id) == allowed - {pin.cpu}
            late = threading.Thread(target=stop.wait, daemon=True)  # started later: inherits the pin ...
            late.start()
            pin.refresh()  # ... until the next refresh moves it
            assert os.sched_getaffinity(late.native_id) == allowed - {pin.cpu}
    finally:
        pin.restore()
        assert os.sched_getaffinity(0) == allowed and os.sched_getaffinity(other.native_id) == allowed
        if len(allowed) > 1:
            assert os.sched_getaffinity(late.native_id) == allowed  # not left on the loop's CPU
        stop.set()
        other.join()
    monkeypatch.setenv("FACTR2_NO_RT", "1")
    off = LoopCpu()
    off.start()
    assert "off" in off.note and os.sched_getaffinity(0) == allowed


@linux
def test_loop_cpu_and_process_threads_take_the_helpers_they_are_handed(monkeypatch):
    """A loop's helper processes come from the loop (its estimators), not from a process-wide registry."""
    import subprocess
    import sys

    from hardware.realtime import LoopCpu, ProcessThreads

    monkeypatch.delenv("FACTR2_NO_RT", raising=False)
    monkeypatch.delenv("FACTR2_NO_PIN", raising=False)
    allowed = set(os.sched_getaffinity(0))
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    def helpers():
        return {child.pid: 3}

    pin, services = LoopCpu(helpers=helpers), ProcessThreads(priority=4, helpers=helpers)
    try:
        pin.start()
        services.refresh()
        if len(allowed) > 1:
            assert os.sched_getaffinity(child.pid) == allowed - {pin.cpu}
        if services.note is None and set_fifo(LOOP_PRIORITY) is None:  # permitted here
            set_normal()
            assert os.sched_getscheduler(child.pid) == os.SCHED_FIFO
            assert os.sched_getparam(child.pid).sched_priority == 3
    finally:
        pin.restore()
        services.restore()
        assert os.sched_getaffinity(child.pid) == allowed
        assert os.sched_getscheduler(child.pid) == os.SCHED_OTHER
        child.kill()
        child.wait()
