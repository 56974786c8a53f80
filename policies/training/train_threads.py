"""The CPU side of a policy training run, beside its loop (policies/training/train.py calls it once a step).

A training shares its machine: with other work (two torch threads on two busy cores thrash), and with a
teleop loop that owns a CPU (hardware/realtime.py). `TrainCpu` owns every choice about that:
- the torch thread count (`pick_threads`: the free cores, split over the run's processes), set once;
- a `ThreadProbe` (calibration/next/threads.py) that re-checks one thread against several every 400 steps
  and drops to one on a collapse (only when the count was chosen, not asked with --threads);
- every thread kept off the CPUs live loops claim (`KeepOffLoopCpus`);
- on rank 0 with progress, two lines: what a CPU image run will cost (policies/training/cost_hint.py) and a
hint when
  the run falls far below the speed it already reached.

    cpu = TrainCpu(cfg.threads, d.world)            # before the model is built
    cpu.watch(start, print, cost=progress, steps_left=..., observation=..., device=..., batch=...)  # rank 0
    for s in ...:
        cpu.before_step(s)
        ...  # the step
        cpu.after_step(done, time.perf_counter())
        cpu.speed(samples_per_s, done)              # when a row is logged
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import torch

from hardware.realtime import KeepOffLoopCpus

PROBE_PERIOD = 100  # steps: the ThreadProbe's "epoch" (it probes every PROBE_EVERY of them)
SLOW_SHARE = 0.3  # a logged speed below this share of the run's best says slow_hint (once)
SLOW_AFTER = 100  # steps of this invocation before the speed is judged


def pick_threads(requested: int, world: int) -> tuple[int, str]:
    """(torch threads, why) for one training process of `world`: the cores this process may use, shared by
    the processes of the run, less the cores other work keeps busy now (the 1-minute load average). Two
    threads on two cores thrash as soon as anything else runs (measured 35 samples/s against 320 on one
    thread: a descheduled thread stalls every barrier), so a busy machine gets fewer threads, and the
    ThreadProbe in the loop drops to one when several turn out slower."""
    from calibration.next.train import available_cores

    if requested > 0:
        return requested, "as asked (--threads)"
    cores = available_cores()
    share = max(1, cores // max(1, world))
    try:
        busy = os.getloadavg()[0]
    except OSError:  # not available on this OS
        busy = 0.0
    free = max(1, int(cores - busy + 0.5))
    n = max(1, min(share, free))
    return n, f"{n} of {cores} cores (load {busy:.1f}{f', {world} processes' if world > 1 else ''})"


def slow_hint(sps: float, best: float, threads: int) -> str:
    """One line when training runs far below the speed this run already reached (other work took cores)."""
    try:
        load = f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    except OSError:
        load = "other work on the cores"
    fix = "pass --threads 1" if threads > 1 else "stop the other work or train on a GPU"
    return (f"training runs at {sps:.0f} samples/s, {best:.0f} earlier in this run ({load}, {threads} "
            f"thread(s)): {fix}")


class TrainCpu:
    """The threads, the probe, the loop's CPU kept free and the cost / slow-down lines of one training
    process (see the module doc)."""

    def __init__(self, requested: int, world: int):
        self.threads, self.why = pick_threads(requested, world)
        torch.set_num_threads(self.threads)
        self.probe = None
        if self.threads > 1 and requested <= 0:
            from calibration.next.threads import ThreadProbe

            self.probe = ThreadProbe(self.threads)  # re-checks 1 thread against n, drops on a collapse
        self.keep_off = KeepOffLoopCpus()  # off the CPU of a teleop loop running beside
        self.cost = None
        self.say: Callable[[str], None] | None = None
        self.start, self.best_sps, self.hinted = 0, 0.0, False

    def watch(self, start: int, say: Callable[[str], None], *, cost: bool, steps_left: int, observation: str,
              device: str, batch: int) -> None:
        """Rank 0: say a slow-down through `say`, and with `cost` what a CPU image run will cost."""
        if cost:
            from policies.training.cost_hint import CostHint  # CPU image runs: what a step and the run cost

            self.cost = CostHint(steps_left, observation=observation, device=device, batch=batch)
        self.start, self.say = start, say

    def before_step(self, s: int) -> None:
        self.keep_off.refresh(time.monotonic())
        if self.probe is not None:
            self.probe.before(s // PROBE_PERIOD, s % PROBE_PERIOD)

    def after_step(self, done: int, now: float) -> None:
        """After global step `done` (1-based) at perf_counter `now` [s]."""
        if self.probe is not None:
            self.probe.after()
        if self.cost is not None and (line := self.cost.tick(done - self.start, now)):
            self.say(line)

    def speed(self, samples_per_s: float, done: int) -> None:
        """A logged speed [samples/s] at global step `done`: once, a line when far below the run's best."""
        if self.say is None:
            return
        self.best_sps = max(self.best_sps, samples_per_s)
        if not self.hinted and done - self.start >= SLOW_AFTER and samples_per_s < SLOW_SHARE * self.best_sps:
            self.hinted = True
            self.say(slow_hint(samples_per_s, self.best_sps, torch.get_num_threads()))
