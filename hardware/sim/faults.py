"""Faults the twin plays on its wires (SIMULATED): a schedule (pure) and the injector that applies it.

    specs = [parse_fault("can_busoff@2.0:0.3"), parse_fault("spike_leader@3.5")]   # KIND@T[:DURATION]
    specs = random_schedule(seed=1, kinds=["can_loss", "dxl_unplug"], n=4, t_min_s=1.0, t_max_s=9.0)
    twin = Twin(rig, faults=specs)          # or the rig's [twin] faults = ["KIND@T[:DURATION]", ...]
    twin.faults.log                         # what was injected and when (the campaign's ground truth)

T and DURATION are seconds of twin (sim) time from the twin's start. Each kind acts on the first follower's
CAN emulator or the first leader's Dynamixel emulator, through the fault knobs those emulators already have
(drop_prob, silent, fault_flags / err, set_hardware_error, corrupt_prob, spike_rad); camera kinds act on
the cameras of the first follower's world (world.camera_fault, read by hardware/cameras/mujoco_camera.py).
A kind the rig's device cannot play is a ConfigError when the twin is built, not a fault silently skipped.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

import numpy as np

from hardware.errors import ConfigError
from hardware.types import STATUS_DRIVER_ERROR, STATUS_OVERCURRENT, STATUS_OVERTEMP

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
}
CAN_LOSS_PROB = 0.5  # each frame lost with this probability during a can_loss burst
DXL_CORRUPT_PROB = 0.5  # each status packet corrupted with this probability during a dxl_corrupt storm
SPIKE_RAD = 1.0  # rad: an encoder glitch's jump (far beyond any motion in one sample)
DEFAULT_JOINT = 1  # joint index a parsed fault acts on (J2: a shoulder joint under gravity load)
DXL_OVERLOAD_BIT = 1 << 5  # Hardware Error Status(70) bit 5: overload
_FLAGS = {"motor_overcurrent": STATUS_OVERCURRENT, "motor_overtemp": STATUS_OVERTEMP,
          "motor_encoder": STATUS_DRIVER_ERROR}
_DAMIAO_ERR = {"motor_overcurrent": 0xA, "motor_overtemp": 0xC, "motor_encoder": 0x8}  # damiao.protocol ERR_*


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


def _can_play(kind: str, emu) -> bool:
    """Whether this emulator has the knob the kind turns."""
    if emu is None:
        return False
    if kind.startswith("motor_"):
        return hasattr(emu, "fault_flags") or hasattr(emu, "err")
    if kind.startswith("spike_"):
        return hasattr(emu, "spike_rad")
    return True


class FaultInjector:
    """Applies a schedule to a twin's emulators as sim time passes (Twin calls on_time after each advance).
    log: one dict per start/end: {"kind", "event": "start" | "end", "t_s" (sim time), "joint", "detail"}."""

    def __init__(self, twin, specs: list[FaultSpec]):
        self.specs = sorted(specs, key=lambda s: s.t_s)
        self.log: list[dict] = []
        self._follower = next((d for d in twin.devices.values() if d.wire == "can"), None)
        self._worlds = [twin.devices[twin.rig.followers[0].name].world] if twin.rig.followers else []
        self._leader = next((d for d in twin.devices.values() if d.wire == "serial"), None)
        for s in self.specs:
            self._target(s)  # a kind this rig cannot play: ConfigError now
        self._started = [False] * len(self.specs)
        self._ended = [False] * len(self.specs)
        self._saved: dict[int, object] = {}

    def _target(self, s: FaultSpec):
        if s.kind.startswith("camera_"):
            if not self._worlds:
                raise ConfigError(f"fault {s.text()}: this twin has no world", where="fault schedule",
                                  fix="drop it")
            return None, None
        dev = self._leader if s.kind.startswith(("dxl_", "spike_leader")) else self._follower
        emu = None if dev is None else dev.emulator
        if not _can_play(s.kind, emu):
            raise ConfigError(f"fault {s.text()} cannot be played on this rig (its twin device has no such "
                              "fault)", where="[twin] faults / --twin-fault",
                              fix="drop it, or use a rig whose device plays it (sim-piper plays every kind)")
        if not 0 <= s.joint < dev.n_arm:
            raise ConfigError(f"fault {s.text()}: joint {s.joint} out of range", where="fault schedule",
                              fix=f"use 0..{dev.n_arm - 1}")
        return dev, emu

    def on_time(self, t_s: float) -> None:
        """Start / end every fault due at sim time t_s [s]."""
        for i, s in enumerate(self.specs):
            if not self._started[i] and t_s >= s.t_s:
                self._started[i] = True
                self._apply(i, s, start=True, t_s=t_s)
            if self._started[i] and not self._ended[i] and t_s >= s.t_s + s.duration_s:
                self._ended[i] = True
                self._apply(i, s, start=False, t_s=t_s)

    def _apply(self, i: int, s: FaultSpec, start: bool, t_s: float) -> None:
        dev, emu = self._target(s)
        k, j, detail = s.kind, s.joint, ""
        if k == "can_loss":
            if start:
                self._saved[i] = emu.drop_prob
            emu.drop_prob = CAN_LOSS_PROB if start else self._saved.pop(i)
        elif k == "can_busoff":
            if start:
                self._saved[i] = emu.drop_prob
            emu.silent, emu.drop_prob = (True, 1.0) if start else (False, self._saved.pop(i))
        elif k.startswith("motor_"):
            if hasattr(emu, "fault_flags"):
                emu.fault_flags[j] = _FLAGS[k] if start else 0
            else:
                emu.err[j] = _DAMIAO_ERR[k] if start else 0
        elif k == "dxl_unplug":
            emu.set_silent(start)
        elif k == "dxl_overload":
            if start:  # latched by the servo until it is rebooted: nothing to undo at the end
                sid = emu.servos[j].id
                emu.set_hardware_error(sid, DXL_OVERLOAD_BIT)
                detail = f"servo id {sid}"
        elif k == "dxl_corrupt":
            emu.corrupt_prob = DXL_CORRUPT_PROB if start else 0.0
        elif k.startswith("camera_"):
            for w in self._worlds:
                w.camera_fault = k.removeprefix("camera_") if start else None
        elif k.startswith("spike_") and start:
            spike = np.zeros(6 if k == "spike_follower" else dev.bank.n)
            spike[j] = SPIKE_RAD
            emu.spike_rad = spike
            detail = f"{SPIKE_RAD:g} rad"
        self.log.append({"kind": k, "event": "start" if start else "end", "t_s": float(t_s), "joint": j,
                         "detail": detail})
