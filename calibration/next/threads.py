"""Thread count of NEXT training on a shared CPU (ThreadProbe; used by calibration.next.train)."""

from __future__ import annotations

import math
import time

import torch


class ThreadProbe:
    """Picks the CPU thread count while training: on a machine shared with other work, oneDNN's LSTM on 2
    threads can run 10x slower than on 1 (a descheduled thread stalls every barrier; measured 24 vs 380
    windows/s at load 12 on 2 cores, 1611 vs ~800 when quiet). Every PROBE_EVERY epochs, batch 1 runs on
    all cores and batch 2 on one thread, each timed; the rest run on the faster. Because the costly failure
    is many threads on a machine that just got busy, every batch on all cores is timed too, and one slower
    than COLLAPSE x its probe drops to one thread until the next probe."""

    PROBE_EVERY = 4
    COLLAPSE = 2.5

    def __init__(self, cores: int, clock=time.perf_counter):
        self.cores, self.threads = cores, cores
        self.clock = clock  # s: what batches are timed with (a test passes its own)
        self._timing: dict[int, float] = {}
        self._t = None
        self._n = None
        self._probing = False

    def before(self, epoch: int, batch: int) -> None:
        if self.cores <= 1:
            return
        self._probing = epoch % self.PROBE_EVERY == 0 and batch in (1, 2)
        if epoch % self.PROBE_EVERY == 0 and batch == 3 and len(self._timing) == 2:  # both timed
            self.threads = min(self._timing, key=self._timing.get)
            torch.set_num_threads(self.threads)
        if self._probing:
            self._n = self.cores if batch == 1 else 1
            torch.set_num_threads(self._n)
        else:
            self._n = self.threads
        self._t = self.clock()

    def after(self) -> None:
        if self._t is None:
            return
        took = self.clock() - self._t
        self._t = None
        if self._probing:
            self._timing[self._n] = took
        elif self._n > 1 and took > self.COLLAPSE * self._timing.get(self._n, math.inf):
            self.threads = 1
            torch.set_num_threads(1)
