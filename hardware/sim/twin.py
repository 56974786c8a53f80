"""The MuJoCo twin of a rig (SIMULATED): physics worlds, motor banks and the real wire protocols.

    twin = Twin(load_rig("sim-piper"), effect=None)       # builds worlds, banks and emulators
    twin.attach(lockstep_clock)   # lockstep: clock.sleep(dt) advances the physics (deterministic per seed)
    twin.start_realtime()         # or: a thread steps the physics to wall time
    twin.serial_ports / twin.can_channels                  # device name -> pty path / virtual CAN channel
    Twin(rig, faults=[FaultSpec, ...])                     # faults on the wires (hardware/sim/faults.py)

Each follower is its own MuJoCo world (its arm's scene, e.g. with a table) with one MujocoBank on the arm
joints (+ gripper); it speaks its driver's protocol through PiperEmulator / DamiaoEmulator on a python-can
virtual channel. Each leader (a GELLO arm) is a separate world without contacts, driven by goal currents
through a DynamixelEmulator on a pseudo-terminal (dynamixel_transport="pty", real time and serve_twin) or
on an in-process port (dynamixel_transport="inprocess", lockstep rigs: hardware/dynamixel/inprocess.py, same
sdk bytes without the pty and its thread). Each device's emulator comes from its kind (hardware/registry.py:
the device folder's make_twin_emulator); this module names no driver. Physics steps at the rig's
physics_hz (1 kHz default): per step the CAN emulators take pending commands (poll), every world steps,
and the CAN emulators send the feedback due (emit). Dynamixel requests are answered by the emulator's
thread from the latest state.

Each arm's world simulates its true body (hardware/arms/true_body.py: the description with a real unit's mass,
COM, inertia and armature errors, drawn from the RIG's [twin] seed: one physical unit per rig file, whatever
seed a run passes for its noise; TwinDevice.body_error says what was drawn) unless the rig's [twin]
description_error is false; the drivers, the app and its models only see the description.

Time: sim time t starts at 0; the rig clock reads t + offset (rig_time()). Emulators stamp frames and
servo ticks with rig_time(), never with the wall clock, so a lockstep run is the same on any machine.
Three ways to drive it: attach(lockstep_clock); start_realtime() (a thread); or the caller's own thread
through TwinDrivenClock (twin_driven_clock.py: rebase(), then catch_up(now) after each sleep). A device's
parameters and MuJoCo model: twin_devices.py.
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from hardware.errors import ConfigError
from hardware.realtime import EMULATOR_PRIORITY, TWIN_PRIORITY, set_fifo
from hardware.registry import EmulatorContext, device_kind
from hardware.sim.effects_hook import load_hook
from hardware.sim.fault_injector import FaultInjector
from hardware.sim.mujoco_bank import MujocoBank
from hardware.sim.twin_devices import TwinDevice, device_model, device_params, twin_effects
from hardware.sim.world import GroundTruth, MujocoWorld

if TYPE_CHECKING:  # the rig loader uses this package (actuator names); the twin only reads a Rig
    from hardware.rigs.rig import DeviceSpec, Rig
# Hz: firmware-law rate of leader worlds. A GELLO leader runs in current mode (its law is K * i, the current
# changes once per driver loop) and is light, so its bank math runs every 2 ms while MuJoCo still integrates
# it at physics_hz (implicit damping + friction slope every physics step); tests/test_twin_speed.py checks the
# motion against the leader stepped every 1 ms. None: the twin's control_hz.
LEADER_CONTROL_HZ = 500.0
REALTIME_SLEEP_S = 0.0005  # s: the real-time thread's nap between catch-ups
REALTIME_MAX_LAG_S = 0.1  # s: a real-time twin further behind than this skips ahead (counted in .overruns)
# The simulated operator's hand that holds a real-time twin's leaders at their start pose until the app's loop
# has them (Twin.hold_leaders_at_start): a relaxed hand, as the terminal app's (2-5 N*m/rad), far stronger
# than a GELLO joint's gravity load (0.13 N*m at most on the YAM GELLO's wrist: it sags 0.04 rad)
START_HAND_K_NM_RAD = 3.0
START_HAND_D_NMS_RAD = 0.1
START_HAND_TAU_MAX_NM = 2.0
_SERIAL = itertools.count()


class Twin:
    """Simulated rig. Device names are the rig's; see module doc for the stepping order."""

    def __init__(self, rig: Rig, *, effect=None, seed: int | None = None, dynamixel_transport: str = "pty",
                 leader_control_hz: float | None = LEADER_CONTROL_HZ, task=None, faults=None):
        from hardware.arms import load_arm
        from hardware.sim.tasks import get_task

        self.rig = rig
        self.seed = rig.twin.seed if seed is None else int(seed)
        self.effects = twin_effects(rig.twin.effects)
        self.description_error = bool(getattr(rig.twin, "description_error", True))
        hook_spec = effect if effect is not None else rig.twin.effect
        self.hook = None
        if hook_spec:
            n_check = load_arm(rig.followers[0].arm).n_joints
            self.hook = load_hook(hook_spec, n_check=n_check)
        self.hook_spec = hook_spec
        # task objects in the follower scenes (hardware/sim/tasks): the argument, else the rig's [twin] task
        self.task = get_task(task if task is not None else getattr(rig.twin, "task", None))
        if dynamixel_transport not in ("pty", "inprocess"):
            raise ConfigError(f"unknown Dynamixel transport {dynamixel_transport!r}", where="Twin",
                              fix="use 'pty' or 'inprocess'")
        self.dynamixel_transport = dynamixel_transport
        # leader worlds take one control tick of leader_every twin ticks (at the end of each block, so at
        # multiples of leader_every * dt they are exactly in time with the followers)
        chz = rig.twin.control_hz
        self.leader_every = max(1, int(chz // leader_control_hz)) if leader_control_hz else 1
        self._every: list[int] = []  # per world: twin ticks per world control tick
        self._idle: set[int] = set()  # indices of worlds not stepped (set_idle)
        self._start_held: set[str] = set()  # leaders the start hand holds (hold_leaders_at_start)
        self.substeps = max(1, round(rig.twin.physics_hz / rig.twin.control_hz))
        self.dt = self.substeps / rig.twin.physics_hz  # control tick [s]: emulators and firmware laws run
        self.devices: dict[str, TwinDevice] = {}
        self.worlds: list[MujocoWorld] = []
        self._can_emus: list = []
        self._dxl_emus: list = []
        self._tag = f"factr2-twin-{os.getpid()}-{next(_SERIAL)}"
        self.t = 0.0
        self._t_offset = 0.0
        self.lock = threading.RLock()
        self._rt_thread: threading.Thread | None = None
        self.realtime_note = None  # why the real-time twin runs at normal priority, if it does
        self._rt_stop = threading.Event()
        self.overruns = 0
        self._step_observers: list = []  # add_step_observer
        self.steps = 0
        self.faults: FaultInjector | None = None
        try:
            for k, dev in enumerate(rig.followers):
                self._add(dev, load_arm(dev.arm), follower=True, seed=self.seed + 101 * k,
                          body_seed=rig.twin.seed + 101 * k)
            for k, dev in enumerate(rig.leaders):
                self._add(dev, load_arm(dev.arm), follower=False, seed=self.seed + 7919 + 101 * k,
                          body_seed=rig.twin.seed + 7919 + 101 * k)
            # faults to play (hardware/sim/faults.py): the argument, else the rig's [twin] faults
            specs = list(faults) if faults is not None else list(getattr(rig.twin, "faults", ()))
            self.faults = FaultInjector(self, specs) if specs else None
        except BaseException:
            self.close()
            raise

    # -- construction ----------------------------------------------------------------------------------
    def _add(self, dev: DeviceSpec, arm, follower: bool, seed: int, body_seed: int) -> None:
        model, body_error = device_model(arm, follower, self.rig.twin.scene, self.task,
                                         body_seed if self.description_error else None)
        model.opt.timestep = self.dt / self.substeps
        world = MujocoWorld(model, name=dev.name)
        kind = device_kind(dev.driver, where=f"rig {dev.name}")
        drive = kind.twin_drive(dev.config)
        # the gripper motor is the bank's last one when the arm has a gripper joint and the device drives it
        with_gripper = bool(arm.gripper_joints) and drive.gripper
        joints = list(arm.joint_names) + ([arm.gripper_joints[0]] if with_gripper else [])
        params = device_params(dev, drive, arm, with_gripper, self.effects)
        bank = world.add_bank(joints, params, name=dev.name, seed=seed)
        every = 1 if follower else self.leader_every
        world.set_substeps(self.substeps * every)
        self._every.append(every)
        if follower and self.hook is not None:
            bank.hook = self.hook
            bank.hook_n = arm.n_joints
        q0 = np.zeros(len(joints))
        if dev.twin_start_q is not None:
            q0[: len(dev.twin_start_q)] = dev.twin_start_q
        jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in joints]
        lo, hi = model.jnt_range[jids].T
        limited = model.jnt_limited[jids] > 0
        world.set_qpos(bank, np.where(limited, np.clip(q0, lo, hi), q0))
        td = TwinDevice(spec=dev, world=world, bank=bank, n_arm=arm.n_joints, wire=kind.wire,
                        body_error=body_error)
        self.worlds.append(world)
        self.devices[dev.name] = td
        if kind.wire is not None:
            ctx = EmulatorContext(spec=dev, bank=bank, world=world, with_gripper=with_gripper, seed=seed,
                                  twin_seed=self.seed, channel=f"{self._tag}-{dev.name}",
                                  dynamixel_transport=self.dynamixel_transport, now=self.rig_time)
            ep = kind.make_emulator(ctx)
            td.emulator, td.endpoint, td.bus = ep.emulator, ep.endpoint, ep.bus
            (self._can_emus if kind.wire == "can" else self._dxl_emus).append(ep.emulator)

    # -- endpoints ---------------------------------------------------------------------------------------
    @property
    def endpoints(self) -> dict[str, str]:
        """Device name -> where its emulator serves it (devices with a wire)."""
        return {n: d.endpoint for n, d in self.devices.items() if d.wire is not None}

    @property
    def serial_ports(self) -> dict[str, str]:
        return {n: d.endpoint for n, d in self.devices.items() if d.wire == "serial"}

    @property
    def can_channels(self) -> dict[str, str]:
        return {n: d.endpoint for n, d in self.devices.items() if d.wire == "can"}

    @property
    def can_emulators(self) -> list:
        """The CAN emulators, in stepping order (their counters: rx_frames, tx_frames, ...)."""
        return list(self._can_emus)

    def bank(self, name: str) -> MujocoBank:
        return self.devices[name].bank

    # -- stepping --------------------------------------------------------------------------------------
    def step(self, poll: bool = True) -> None:
        """One physics step of every world, with the CAN emulators' poll before (unless poll is False: the
        caller knows no frame can have arrived) and their emit after."""
        if poll:
            for e in self._can_emus:
                e.poll()
        k, idle = self.steps + 1, self._idle
        for i, (w, every) in enumerate(zip(self.worlds, self._every)):
            if (every == 1 or k % every == 0) and i not in idle:
                w.step()
        self.t += self.dt
        self.steps = k
        for e in self._can_emus:
            e.emit(self.t)
        for e in self._dxl_emus:  # the servos' Bus Watchdog on twin time (dynamixel/watchdog.py)
            e.poll_watchdogs()

    def advance(self, t_target: float) -> int:
        """Step until sim time reaches t_target [s] (clock time when attached); returns steps taken."""
        with self.lock:
            for e in self._dxl_emus:  # a sync write sent before the loop slept must land before physics
                e.drain(0.05)
            target, n = t_target - self._t_offset, 0
            # Frames reach the CAN emulators during an advance only from other threads, i.e. while the
            # real-time thread runs the physics; in lockstep (or a loop that steps the twin itself) the
            # clients wait, so one poll at the first step sees everything (same result, ~2 us/step less).
            every = self._rt_thread is not None
            while self.t + 0.5 * self.dt < target:
                self.step(poll=every or n == 0)
                n += 1
            if n and self.faults is not None:
                self.faults.on_time(self.t)
            if n and self._step_observers:
                t_rig = self.t + self._t_offset
                for fn in self._step_observers:
                    fn(t_rig)
            return n

    def set_idle(self, name: str, idle: bool = True) -> None:
        """Stop (idle=False: resume) simulating a device's world, for a device nothing drives or reads (a
        lockstep rollout's passive leader when nothing records it): its physics is CPU spent for no one. Its
        emulator still answers, from the state the world stopped in; the world's time stands still."""
        i = self.worlds.index(self.devices[name].world)
        with self.lock:
            (self._idle.add if idle else self._idle.discard)(i)

    def add_step_observer(self, fn) -> None:
        """fn(t [s, rig clock]) after every advance that stepped, on the stepping thread, the twin's lock held
        (cameras snapshot the physics state here: a frame shows the state at exactly its timestamp)."""
        self._step_observers.append(fn)

    def remove_step_observer(self, fn) -> None:
        if fn in self._step_observers:
            self._step_observers.remove(fn)

    def rig_time(self) -> float:
        """The rig clock's time [s] at the twin's current sim time (what emulators stamp frames with)."""
        return self.t + self._t_offset

    def lag(self, now: float) -> float:
        """How far [s] the twin is behind rig-clock time `now`."""
        return now - self._t_offset - self.t

    def rebase(self, now: float) -> None:
        """Sim time continues from rig-clock time `now` (time before it is not simulated)."""
        self._t_offset = now - self.t

    def catch_up(self, now: float, max_lag_s: float) -> int:
        """Step to rig-clock time `now`; further behind than max_lag_s [s] (a stall), skip ahead to one step
        behind instead (counted in .overruns) rather than spiral. Returns steps taken."""
        if self.lag(now) > max_lag_s:
            self.overruns += 1
            self._t_offset = now - self.t - self.dt
        return self.advance(now)

    def attach(self, clock) -> None:
        """Lockstep: clock.sleep(dt) advances this twin; sim time 0 is the clock's current time."""
        self.rebase(clock.now())
        clock.attach(self.advance)

    def start_realtime(self) -> None:
        """A daemon thread steps the physics to wall time (sim time 0 = now)."""
        if self._rt_thread is not None:
            return
        self._rt_stop.clear()
        self.rebase(time.monotonic())
        self._rt_thread = threading.Thread(target=self._realtime_loop, name="factr2-twin", daemon=True)
        self._rt_thread.start()
        # hardware answers in bounded time whatever else the host runs: the emulators that stand in for it,
        # and the physics behind them, run at real-time priority where the OS allows (hardware.realtime)
        why = set_fifo(TWIN_PRIORITY, self._rt_thread.native_id)
        for e in self._dxl_emus:
            why = e.set_realtime(EMULATOR_PRIORITY) or why
        self.realtime_note = why  # None, or why the twin runs at normal priority (an RtRefusal reason)

    def _realtime_loop(self) -> None:
        while not self._rt_stop.is_set():
            self.catch_up(time.monotonic(), REALTIME_MAX_LAG_S)
            time.sleep(REALTIME_SLEEP_S)

    def stop_realtime(self) -> None:
        if self._rt_thread is not None:
            self._rt_stop.set()
            self._rt_thread.join(timeout=2.0)
            self._rt_thread = None

    # -- the virtual world ---------------------------------------------------------------------------------
    def hold_leaders_at_start(self) -> None:
        """SIMULATED: an operator's hand holds every leader at its start pose (an impedance at the firmware
        rate, START_HAND_*) until release_start_hold(), or until another hand is set. Why: a real-time twin's
        physics runs from its start, and the app's loop takes the leader (gravity compensation) only a few
        hundred ms later. Unheld, the YAM GELLO's wrist (j4) swung down from 0 to -1.75 rad (past its stop)
        in 0.3 s and settled at -1.55, while the follower's wrist was held at -0.72 by its driver: the
        loop's start check saw 0.41-1.03 rad, depending on where the swing was, and refused above its 1 rad
        in about 1 of 3 runs (issue #53). A person holds the leader when starting; so does this hand."""
        for spec in self.rig.leaders:
            dv = self.devices[spec.name]
            n = dv.n_arm
            with dv.world.lock:
                q = dv.world.data.qpos[dv.bank.qadr[:n]].copy()
            dv.bank.set_hand_impedance(q, np.zeros(n), np.full(n, START_HAND_K_NM_RAD),
                                       np.full(n, START_HAND_D_NMS_RAD), np.full(n, START_HAND_TAU_MAX_NM), n)
            self._start_held.add(spec.name)

    def release_start_hold(self) -> None:
        """Let go of the leaders the start hand still holds (the app's loop has them now); a hand set since
        (apply_leader_hand_*: the demo's or the terminal app's operator) is left as it is."""
        for name in sorted(self._start_held):
            dv = self.devices[name]
            dv.bank.set_hand_torque(np.zeros(dv.n_arm), dv.n_arm)
        self._start_held.clear()

    def apply_leader_hand_torque(self, tau: np.ndarray, leader: str | None = None) -> None:
        """A virtual operator's hand on a leader's arm joints [N*m] (held until changed)."""
        name = leader or self.rig.leaders[0].name
        self._start_held.discard(name)
        d = self.devices[name]
        d.bank.set_hand_torque(np.asarray(tau, dtype=float).reshape(d.n_arm), d.n_arm)

    def apply_leader_hand_impedance(self, q_ref, qd_ref, k, d, tau_max, leader: str | None = None) -> None:
        """A virtual operator's hand on a leader's arm joints as an impedance toward q_ref [rad], qd_ref
        [rad/s] (MujocoBank.set_hand_impedance: computed at the firmware rate from the true joints)."""
        name = leader or self.rig.leaders[0].name
        self._start_held.discard(name)
        dv = self.devices[name]
        dv.bank.set_hand_impedance(q_ref, qd_ref, k, d, tau_max, dv.n_arm)

    def push(self, link: str, force, duration_s: float, follower: str | None = None) -> None:
        """Push a follower's body `link` with a world-frame force [N] at its centre of mass for duration_s."""
        d = self.devices[follower or self.rig.followers[0].name]
        d.world.push(link, np.asarray(force, dtype=float), duration_s)

    def ground_truth(self, average_s: float = 0.0) -> dict[str, GroundTruth]:
        """Ground truth per device (SIMULATED; see world.GroundTruth); average_s [s]: mean over the physics
        steps of that last stretch -- pass the caller's sample period (world.MujocoWorld.ground_truth)."""
        return {n: self.device_ground_truth(n, average_s) for n in self.devices}

    def device_ground_truth(self, name: str, average_s: float = 0.0) -> GroundTruth:
        """Ground truth of one device: computes only its world (what a per-tick caller needs)."""
        d = self.devices[name]
        return d.world.ground_truth(average_s)[d.world.banks.index(d.bank)]

    def close(self) -> None:
        self.stop_realtime()
        if self.faults is not None:
            self.faults.close()
        for e in self._dxl_emus:
            e.close()
        for d in self.devices.values():
            if d.bus is not None:
                d.bus.shutdown()
        self._dxl_emus, self._can_emus = [], []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
