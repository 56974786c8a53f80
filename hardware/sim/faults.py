"""Faults the twin plays (SIMULATED): the kinds and their schedule (pure). The injector that applies them is
hardware/sim/fault_injector.py (Twin builds it), the process kinds' actions hardware/sim/process_faults.py.

    specs = [parse_fault("can_busoff@2.0:0.3"), parse_fault("spike_leader@3.5")]   # KIND@T[:DURATION]
    specs = random_schedule(seed=1, kinds=["can_loss", "dxl_unplug"], n=4, t_min_s=1.0, t_max_s=9.0)
    twin = Twin(rig, faults=specs)          # or the rig's [twin] faults = ["KIND@T[:DURATION]", ...]
    twin.faults.log                         # what was injected and when (the campaign's ground truth)

T and DURATION are seconds of twin (sim) time from the twin's start. Each kind acts on the first follower's
CAN emulator or the first leader's Dynamixel emulator, through the fault knobs those emulators already have
(drop_prob, silent, fault_flags / err, set_hardware_error, corrupt_prob, spike_rad); camera kinds act on
the cameras of the first follower's world (world.camera_fault, read by hardware/cameras/mujoco_camera.py).
Process kinds (PROCESS_KINDS) act on this process: the NEXT worker killed, the recording's filesystem
filled, SIGTERM / SIGKILL of the app, the wall clock stepped.
A kind the rig's device cannot play is a ConfigError when the twin is built, not a fault silently skipped.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

import numpy as np

from hardware.errors import ConfigError

# kind -> (what it plays, default duration [s]; 0: a single sample)
KINDS: dict[str, tuple[str, float]] = {
    "can_loss": ("follower CAN frames lost in both directions (a burst, CAN_LOSS_PROB each)", 0.2),
    "can_busoff": ("follower CAN bus-off: no frame in or out, then the bus recovers", 0.3),
    "motor_overcurrent": ("a follower motor reports over-current", 0.5),
    "motor_overtemp": ("a follower motor reports over-temperature", 0.5),
    "motor_encoder": ("a follower motor reports a driver/encoder error", 0.5),
    "dxl_unplug": ("the leader's Dynamixel chain stops answering (cable out), then answers again", 0.5),
    "dxl_overload": ("a leader servo latches Hardware Error Status overload (torque off until reboot)", 0.0),
    "dxl_corrupt": ("a storm of corrupted Dynamixel status packets (DXL_CORRUPT_PROB each)", 0.3),
    "spike_leader": ("one leader encoder sample jumps by SPIKE_RAD on one joint", 0.0),
    "spike_follower": ("one follower encoder sample jumps by SPIKE_RAD on one joint", 0.0),
    "camera_freeze": ("the first follower world's cameras keep showing one frame", 1.0),
    "camera_gone": ("the first follower world's cameras deliver nothing (unplugged), then come back", 1.0),
    "next_killed": ("the NEXT worker process is killed (SIGKILL, as the OOM killer does)", 0.0),
    "disk_full": ("the recording's filesystem fills up (another writer takes the space), freed at the end",
                  1.0),
    "app_sigterm": ("the app receives SIGTERM (a service manager stops it)", 0.0),
    "app_sigkill": ("the app is killed with SIGKILL (none of its own code runs)", 0.0),
    "app_freeze": ("the app is stopped (SIGSTOP) for the duration, then continued (SIGCONT)", 2.0),
    "wall_step_fwd": ("the wall clock (time.time) steps WALL_STEP_S forwards, as an NTP correction", 0.0),
    "wall_step_back": ("the wall clock (time.time) steps WALL_STEP_S backwards", 0.0),
}
# kinds that act on this process, not on a device of the rig (hardware/sim/fault_injector.py)
PROCESS_KINDS = ("next_killed", "disk_full", "app_sigterm", "app_sigkill", "app_freeze", "wall_step_fwd",
                 "wall_step_back")
CAN_LOSS_PROB = 0.5  # each frame lost with this probability during a can_loss burst
DXL_CORRUPT_PROB = 0.5  # each status packet corrupted with this probability during a dxl_corrupt storm
WALL_STEP_S = 3600.0  # s: a wall-clock step (larger than any real NTP step: an hour either way)
SPIKE_RAD = 1.0  # rad: an encoder glitch's jump (far beyond any motion in one sample)
DEFAULT_JOINT = 1  # joint index a parsed fault acts on (J2: a shoulder joint under gravity load)
DXL_OVERLOAD_BIT = 1 << 5  # Hardware Error Status(70) bit 5: overload


@dataclass(frozen=True)
class FaultSpec:
    """One scheduled fault: kind (KINDS), t_s [s of twin time], duration_s [s] (0: one sample / latched),
    joint: the joint index it concerns (motor and spike kinds)."""

    kind: str
    t_s: float
    duration_s: float
    joint: int = DEFAULT_JOINT

    def text(self) -> str:
        return f"{self.kind}@{self.t_s:g}:{self.duration_s:g}"


def parse_fault(text: str, where: str = "--twin-fault") -> FaultSpec:
    """`KIND@T[:DURATION]` -> FaultSpec; ConfigError (one line: what, where, how to fix) on bad input."""
    fix = f"write KIND@T[:DURATION] in seconds, e.g. can_busoff@2.0:0.3; kinds: {', '.join(KINDS)}"
    kind, at, rest = str(text).strip().partition("@")
    if not at or kind not in KINDS:
        raise ConfigError(f"bad fault {text!r}" + ("" if not at else f": unknown kind {kind!r}"),
                          where=where, fix=fix)
    t_txt, colon, d_txt = rest.partition(":")
    try:
        t = float(t_txt)
        d = float(d_txt) if colon else KINDS[kind][1]
    except ValueError:
        raise ConfigError(f"bad fault {text!r}: time or duration is not a number", where=where,
                          fix=fix) from None
    if not (np.isfinite(t) and np.isfinite(d)) or t < 0 or d < 0:
        raise ConfigError(f"bad fault {text!r}: time and duration must be finite and >= 0", where=where,
                          fix=fix)
    return FaultSpec(kind, t, d)


def random_schedule(seed: int, kinds: list[str], n: int, t_min_s: float, t_max_s: float,
                    gap_s: float = 1.0, n_joints: int = 6) -> list[FaultSpec]:
    """n faults of the given kinds (round robin, shuffled), at seeded random times in [t_min_s, t_max_s]
    at least gap_s [s] after the previous one ends, each on a random joint; sorted by time."""
    for k in kinds:
        if k not in KINDS:
            raise ConfigError(f"unknown fault kind {k!r}", where="random_schedule",
                              fix=f"use one of {', '.join(KINDS)}")
    rng = random.Random(seed)
    order = [kinds[i % len(kinds)] for i in range(n)]
    rng.shuffle(order)
    out, t = [], t_min_s
    for i, kind in enumerate(order):
        d = KINDS[kind][1]
        left = (t_max_s - t) - sum(KINDS[k][1] + gap_s for k in order[i:])
        t += rng.uniform(0.0, max(left, 0.0) / max(n - i, 1))
        out.append(FaultSpec(kind, round(t, 3), d, joint=rng.randrange(n_joints)))
        t += d + gap_s
    return out
