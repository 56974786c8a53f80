"""The loop's own CPU per tick leaves out what a twin does on the loop's thread (hardware/sim_cpu.py)."""

from __future__ import annotations

import threading
import time

from factr2_teleop.teleop.timing import LoopTiming
from hardware import sim_cpu


def _spin(seconds: float) -> None:
    t0 = time.thread_time()
    while time.thread_time() - t0 < seconds:
        pass


def test_simulated_block_is_charged_to_this_thread_only():
    before = sim_cpu.charged()
    with sim_cpu.simulated():
        _spin(0.02)
    mine = sim_cpu.charged() - before
    assert 0.019 <= mine < 0.2
    other = []
    th = threading.Thread(target=lambda: other.append(sim_cpu.charged()))
    th.start()
    th.join()
    assert other == [0.0]  # another thread (a second loop, the twin's own) saw none of it


def test_timing_splits_app_and_twin_cpu():
    lt = LoopTiming(500.0)
    for k in range(10):
        lt.record(k * 0.002, 0.001, 0.0004, 0.0002)
    st = lt.stats()
    assert abs(st.cpu_mean_ms - 0.4) < 1e-9 and abs(st.sim_cpu_mean_ms - 0.2) < 1e-9
    assert abs(st.cpu_share - 0.2) < 1e-9
    assert "twin 0.20 ms" in st.line()
    hw = LoopTiming(500.0)
    for k in range(10):
        hw.record(k * 0.002, 0.001, 0.0004)
    assert hw.stats().sim_cpu_mean_ms == 0.0 and "twin" not in hw.stats().line()
