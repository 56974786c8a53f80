"""The twin's fault injector (SIMULATED): applies a schedule of hardware/sim/faults.py FaultSpecs to the
twin's emulators and to this process (process_faults.py) as sim time passes.

    twin = Twin(rig, faults=specs)    # builds FaultInjector(twin, specs); Twin.advance calls on_time
    twin.faults.recording_dir = dir   # where disk_full fills (the run's recording folder)
    twin.faults.log                   # what was injected and when (the campaign's ground truth)
"""

from __future__ import annotations

import signal

import numpy as np

from hardware.errors import ConfigError
from hardware.sim import process_faults as PF
from hardware.sim.faults import (
    CAN_LOSS_PROB,
    DXL_CORRUPT_PROB,
    DXL_OVERLOAD_BIT,
    PROCESS_KINDS,
    SPIKE_RAD,
    WALL_STEP_S,
    FaultSpec,
)
from hardware.types import STATUS_DRIVER_ERROR, STATUS_OVERCURRENT, STATUS_OVERTEMP

_FLAGS = {"motor_overcurrent": STATUS_OVERCURRENT, "motor_overtemp": STATUS_OVERTEMP,
          "motor_encoder": STATUS_DRIVER_ERROR}
_DAMIAO_ERR = {"motor_overcurrent": 0xA, "motor_overtemp": 0xC, "motor_encoder": 0x8}  # damiao.protocol ERR_*


def _can_play(kind: str, emu) -> bool:
    """Whether this emulator has the knob the kind turns."""
    if emu is None:
        return False
    if kind.startswith("motor_"):
        return hasattr(emu, "fault_flags") or hasattr(emu, "err")
    if kind.startswith("spike_"):
        return hasattr(emu, "spike_rad")
    return True


def _play_process(kind: str, start: bool, recording_dir, duration_s: float = 0.0) -> str:
    """A process kind (faults.PROCESS_KINDS) at its start / end; the log's detail."""
    if kind == "disk_full":
        return PF.fill_disk(recording_dir) if start else PF.free_disk(recording_dir)
    if not start:
        return ""
    if kind == "next_killed":
        return PF.kill_next_workers()
    if kind.startswith("wall_step_"):
        return PF.step_wall_clock(WALL_STEP_S if kind == "wall_step_fwd" else -WALL_STEP_S)
    if kind == "app_freeze":
        return PF.freeze_app(duration_s)
    return PF.signal_app(signal.SIGTERM if kind == "app_sigterm" else signal.SIGKILL)


class FaultInjector:
    """Applies a schedule to a twin's emulators as sim time passes (Twin calls on_time after each advance).
    log: one dict per start/end: {"kind", "event": "start" | "end", "t_s" (sim time), "joint", "detail",
    "played": False when the fault found nothing to act on (detail says why: no NEXT worker, no recording)}.
    recording_dir: the folder disk_full fills (set by the run that records; None: not played)."""

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
        self.recording_dir = None
        self.wall_stepped = False  # a wall_step_* was played: Twin.close restores time.time

    def _target(self, s: FaultSpec):
        if s.kind in PROCESS_KINDS:
            return None, None
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
        elif k in PROCESS_KINDS:
            self.wall_stepped |= k.startswith("wall_step_")
            detail = _play_process(k, start, self.recording_dir, s.duration_s)
        elif k.startswith("spike_") and start:
            spike = np.zeros(6 if k == "spike_follower" else dev.bank.n)
            spike[j] = SPIKE_RAD
            emu.spike_rad = spike
            detail = f"{SPIKE_RAD:g} rad"
        self.log.append({"kind": k, "event": "start" if start else "end", "t_s": float(t_s), "joint": j,
                         "detail": detail, "played": not detail.startswith("not played")})

    def close(self) -> None:
        """Undo what outlives the twin: the wall clock's step, a filler file."""
        if self.wall_stepped:
            PF.restore_wall_clock()
        PF.free_disk(self.recording_dir)
