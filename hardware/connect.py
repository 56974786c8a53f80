"""Open a rig: its drivers connected to the real hardware or to its twin; or serve a twin on its wires.

    from hardware.connect import open_rig, serve_twin
    twin = serve_twin("sim-piper", effect=None)     # real time, in this process (SIMULATED hardware)
    twin.can_channels   # {"follower": "<virtual channel>"}   python-can interface "virtual"
    twin.serial_ports   # {"leader": "/dev/pts/N"}            Dynamixel Protocol 2.0
    twin.ground_truth() # {"follower": GroundTruth, ...}
    twin.stop()

    with open_rig("sim-piper", clock="lockstep") as s:   # twin + real drivers, lockstep clock
        s.followers["follower"].command(...); s.clock.sleep(0.002)

This module sits above the rig loader (hardware/rigs) and the twin (hardware/sim), which do not import each
other's runtime code; every device is built by its kind (hardware/registry.py).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from hardware.clock import Clock, LockstepClock
from hardware.errors import ConfigError
from hardware.registry import device_kind
from hardware.rigs.rig import Rig, load_rig
from hardware.roles import Follower, Leader, WatchdogThread
from hardware.sim.twin import Twin


class TwinServer:
    """A twin running in real time in this process (returned by serve_twin)."""

    def __init__(self, twin: Twin):
        self.twin = twin

    @property
    def rig(self) -> Rig:
        return self.twin.rig

    @property
    def can_channels(self) -> dict[str, str]:
        """Device name -> python-can virtual channel (open with interface="virtual")."""
        return self.twin.can_channels

    @property
    def serial_ports(self) -> dict[str, str]:
        """Device name -> pseudo-terminal path (use like /dev/ttyUSB0)."""
        return self.twin.serial_ports

    def ground_truth(self, average_s: float = 0.0):
        return self.twin.ground_truth(average_s)

    def push(self, link: str, force, duration_s: float, follower: str | None = None) -> None:
        self.twin.push(link, force, duration_s, follower)

    def apply_leader_hand_torque(self, tau, leader: str | None = None) -> None:
        self.twin.apply_leader_hand_torque(tau, leader)

    @property
    def sim_time(self) -> float:
        return self.twin.t

    def stop(self) -> None:
        self.twin.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
        return False


def _as_rig(rig: str | os.PathLike | Rig) -> Rig:
    return rig if isinstance(rig, Rig) else load_rig(rig)


def serve_twin(rig: str | os.PathLike | Rig = "sim-piper", effect=None,
               seed: int | None = None) -> TwinServer:
    """Start a rig's twin in real time in the current process. effect: "MODULE:FUNCTION" or a callable
    f(t, q, q_dot) -> tau [N*m] (undeclared effect on the followers). ConfigError for a non-simulated rig."""
    r = _as_rig(rig)
    if not r.simulated:
        raise ConfigError(f"rig {r.name} is real hardware, there is no twin to serve", where=str(r.path),
                          fix="use a sim-* rig (factr2 twin --rig sim-piper)")
    twin = Twin(r, effect=effect, seed=seed)
    twin.start_realtime()
    return TwinServer(twin)


@dataclass
class RigSession:
    """A rig's devices, connected through their real drivers (and its twin when simulated).

    leaders / followers: name -> driver (hardware.roles Leader / Follower); pairs: (leader, follower) driver
    pairs in the rig's pairing; clock: the session clock (LockstepClock or Clock); twin: the Twin or None;
    simulated: True when the devices are the twin's."""

    rig: Rig
    clock: Clock
    twin: Twin | None
    leaders: dict[str, Leader] = field(default_factory=dict)
    followers: dict[str, Follower] = field(default_factory=dict)
    cameras: dict = field(default_factory=dict)  # name -> hardware.cameras Camera (not connected)
    watchdog: WatchdogThread | None = None

    @property
    def simulated(self) -> bool:
        return self.twin is not None

    @property
    def pairs(self) -> list[tuple[Leader, Follower]]:
        return [(self.leaders[a], self.followers[b]) for a, b in self.rig.pairs
                if a in self.leaders and b in self.followers]

    @property
    def leader(self) -> Leader:
        return next(iter(self.leaders.values()))

    @property
    def follower(self) -> Follower:
        return next(iter(self.followers.values()))

    def ground_truth(self, average_s: float = 0.0):
        """SIMULATED ground truth per device (None on real hardware); average_s: see Twin.ground_truth."""
        return self.twin.ground_truth(average_s) if self.twin else None

    def disconnect_arms(self) -> None:
        """Every follower, then every leader, through its driver's disconnect (a follower held or disabled as
        its driver does, a leader at zero torque and torque off). An app calls it as soon as its loop has
        stopped, before slower closing work (a recording's): a motor left without commands that long falls
        back by its own timeout (a leader's Bus Watchdog latches, a Damiao motor drops to damping) instead of
        being put down. close() does it too; a device already disconnected is passed over."""
        if self.watchdog is not None:
            self.watchdog.stop()
        for d in list(self.followers.values()) + list(self.leaders.values()):
            try:
                d.disconnect()
            except Exception:  # closing must reach every device and the twin
                pass

    def close(self) -> None:
        if self.watchdog is not None:
            self.watchdog.stop()
        for cam in self.cameras.values():
            try:
                cam.disconnect()
            except Exception:  # closing must reach every device and the twin
                pass
        self.disconnect_arms()
        if self.twin is not None:
            self.twin.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def make_driver(spec, clock: Clock, twin: Twin | None = None):
    """The driver object for one rig device (not connected), built by its kind."""
    return device_kind(spec.driver, where=f"rig device {spec.name}").make_driver(spec, clock, twin)


def make_cameras(rig: Rig, twin: Twin | None, clock: Clock) -> dict:
    """Camera objects (not connected) for the rig's [[cameras]]: "sim:<camera>" (or "sim:<device>:<camera>")
    renders an MJCF camera of a twin world (the first follower's by default); anything else is an OpenCV
    device path or index."""
    out = {}
    for c in rig.cameras:
        if c.source.startswith("sim:"):
            from hardware.cameras.mujoco_camera import MujocoCameraConfig

            if twin is None:
                raise ConfigError(f"camera {c.name} renders the twin ({c.source}) on a real-hardware rig",
                                  where=f"{rig.path}: cameras", fix="use a device path, e.g. /dev/video0")
            dev, _, cam = c.source[4:].rpartition(":")
            dev = dev or rig.followers[0].name
            if dev not in twin.devices:
                raise ConfigError(f"camera {c.name}: no twin device {dev!r}", where=f"{rig.path}: cameras",
                                  fix=f"use one of {', '.join(sorted(twin.devices))}")
            world = twin.devices[dev].world
            cfg = MujocoCameraConfig(name=c.name, width=c.width, height=c.height, fps=c.fps, camera=cam)
            out[c.name] = _twin_camera(cfg, world, clock)
        else:
            from hardware.cameras.opencv_camera import OpenCVCamera, OpenCVCameraConfig

            out[c.name] = OpenCVCamera(OpenCVCameraConfig(name=c.name, width=c.width, height=c.height,
                                                          fps=c.fps, device=c.source), clock)
    return out


def _twin_camera(config, world, clock):
    """A camera on a twin world (the camera module is imported only when a rig has cameras)."""
    from hardware.cameras.mujoco_camera import TwinCamera

    return TwinCamera(config, world, clock)


def open_rig(rig: str | os.PathLike | Rig = "sim-piper", clock: str = "lockstep", effect=None,
             seed: int | None = None, connect: bool = True,
             dynamixel_transport: str | None = None, faults=None) -> RigSession:
    """Open a rig: a RigSession, what the session layer runs on. Simulated rigs get a Twin:
    clock="lockstep" (deterministic; the loop's clock.sleep advances physics) or "realtime" (a thread
    steps physics to wall time). Real rigs need clock="realtime". connect: connect every driver (leaders
    first). Cameras are built, not connected (session.cameras[name].connect(); twin cameras need OpenGL).
    dynamixel_transport: how a twin serves its Dynamixel leaders -- None picks "inprocess" for lockstep
    (same sdk bytes, no pty thread: deterministic and fast) and "pty" for realtime; "pty" in lockstep
    exercises the pseudo-terminal path.
    faults: hardware.sim.faults.FaultSpec the twin plays (None: the rig's [twin] faults; a real rig: error).
    ConfigError on bad input."""
    r = _as_rig(rig)
    if clock not in ("lockstep", "realtime"):
        raise ConfigError(f"unknown clock {clock!r}", where="open_rig", fix="use 'lockstep' or 'realtime'")
    twin = None
    if r.simulated:
        transport = dynamixel_transport or ("inprocess" if clock == "lockstep" else "pty")
        twin = Twin(r, effect=effect, seed=seed, dynamixel_transport=transport, faults=faults)
        r = r.with_endpoints(twin.endpoints)
    elif clock == "lockstep":
        raise ConfigError(f"rig {r.name} is real hardware: it cannot run in lockstep", where=str(r.path),
                          fix="use clock='realtime'")
    elif effect is not None:
        raise ConfigError("a twin effect needs a simulated rig", where="--twin-effect", fix="use a sim-* rig")
    elif faults:
        raise ConfigError("twin faults need a simulated rig", where="--twin-fault", fix="use a sim-* rig")
    clk: Clock = LockstepClock() if clock == "lockstep" else Clock()
    session = RigSession(rig=r, clock=clk, twin=twin)
    try:
        if twin is not None:
            if clock == "lockstep":
                twin.attach(clk)
            else:  # held as a person holds it until the app's loop has it (Twin.hold_leaders_at_start)
                twin.hold_leaders_at_start()
                twin.start_realtime()
        for spec in r.leaders:
            session.leaders[spec.name] = make_driver(spec, clk, twin)
        for spec in r.followers:
            session.followers[spec.name] = make_driver(spec, clk, twin)
        session.cameras = make_cameras(r, twin, clk)
        if connect:
            for d in list(session.leaders.values()) + list(session.followers.values()):
                d.connect()
            if clock == "realtime":
                devices = list(session.leaders.values()) + list(session.followers.values())
                session.watchdog = WatchdogThread(devices)
                session.watchdog.start()
    except BaseException:
        session.close()
        raise
    return session
