"""What an image training run on a CPU will cost, said up front (issue #31 item 5).

Training on camera frames on a CPU is slow (the small preset: about 3.3 s per step at batch 128 on the 2-vCPU
dev VM, 300 steps in 16.6 min), and a run used to say nothing about it. After the first few steps the loop
knows what a step costs; `CostHint` turns that into one line: the step time, what the run's remaining steps
will take and when they end, and the two ways out (`--obs state` on a twin, or a GPU). Nothing is printed for
a GPU run or for a run without images. Pure: the clock is passed in.

    hint = CostHint(total - start, observation=pcfg.observation, device=d.device.type, batch=cfg.batch)
    ...  # in the loop, after each step, rank 0:
    line = hint.tick(done - start, time.perf_counter())
    if line:
        print(line)
"""

from __future__ import annotations

import time

import numpy as np

WARMUP_STEPS = 1  # the first step (allocation, first-touch of the frame caches) is not timed
TIMED_STEPS = 3  # steps whose median gives the estimate: ~10 s of a CPU image run before the line


def fmt_duration(s: float) -> str:
    """12 s, 4.5 min, 2.3 h."""
    if not np.isfinite(s):
        return "?"
    if s < 90:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{s / 60:.1f} min"
    return f"{s / 3600:.1f} h"


def cost_line(step_s: float, steps_left: int, *, batch: int, observation: str = "images",
              now: float | None = None) -> str:
    """The line: what a step costs, what the rest of the run takes and when it ends, and the ways out."""
    total = step_s * max(0, int(steps_left))
    end = time.strftime("%H:%M", time.localtime((time.time() if now is None else now) + total))
    return (f"training on camera frames ({observation}) on the CPU: {step_s:.2f} s per step at batch "
            f"{batch}, the {steps_left} steps left take about {fmt_duration(total)} (until about {end}; "
            "validation and checkpoints extra). Faster: on a twin's task recordings, --obs state "
            "(PRIVILEGED object state, no images); or train on a machine with a GPU (CUDA is used there)")


class CostHint:
    """Times the first steps of a run and says, once, what the run will cost (CPU image runs only)."""

    def __init__(self, steps_left: int, *, observation: str, device: str, batch: int,
                 warmup: int = WARMUP_STEPS, timed: int = TIMED_STEPS):
        from policies.data.privileged import uses_images

        self.active = uses_images(observation) and device == "cpu" and steps_left > warmup + timed
        self.steps_left, self.observation, self.batch = int(steps_left), observation, int(batch)
        self.warmup, self.timed = int(warmup), int(timed)
        self._t: list[tuple[int, float]] = []  # (step, clock) at the end of steps warmup, warmup + 1, ...
        self.step_s: float | None = None

    def tick(self, done: int, now: float, wall: float | None = None) -> str | None:
        """After step `done` (steps of this invocation, 1-based) at clock `now` [s]: the line once the timed
        steps are done, else None. wall: the epoch time for the end estimate (default time.time())."""
        if not self.active or self.step_s is not None or done < self.warmup:
            return None
        self._t.append((int(done), float(now)))
        if done - self._t[0][0] < self.timed:
            return None
        steps, clock = np.asarray(self._t, float).T
        self.step_s = float(np.median(np.diff(clock) / np.maximum(np.diff(steps), 1)))
        return cost_line(self.step_s, self.steps_left - done, batch=self.batch, observation=self.observation,
                         now=wall)
