"""The MuJoCo twin of a rig (SIMULATED): physics worlds, motor banks and the real wire protocols.

    twin = Twin(load_rig("sim-piper"), effect=None)       # builds worlds, banks and emulators
    twin.attach(lockstep_clock)   # lockstep: clock.sleep(dt) advances the physics (deterministic per seed)
    twin.start_realtime()         # or: a thread steps the physics to wall time
    twin.serial_ports / twin.can_channels                  # device name -> pty path / virtual CAN channel

Each follower is its own MuJoCo world (its arm's scene, e.g. with a table) with one MujocoBank on the arm
joints (+ gripper); it speaks its driver's protocol through PiperEmulator / DamiaoEmulator on a python-can
virtual channel. Each leader (a GELLO arm) is a separate world without contacts, driven by goal currents
through a DynamixelEmulator on a pseudo-terminal (dynamixel_transport="pty", real time and serve_twin) or
on an in-process port (dynamixel_transport="inprocess", lockstep rigs: hardware/dynamixel/inprocess.py, same
sdk bytes without the pty and its thread). Physics steps at the rig's physics_hz (1 kHz default):
per step the CAN emulators take pending commands (poll), every world steps, and the CAN emulators send
the feedback due (emit). Dynamixel requests are answered by the emulator's thread from the latest state.
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from dataclasses import dataclass, replace

import mujoco
import numpy as np

from hardware.errors import ConfigError
from hardware.rigs.rig import DeviceSpec, Rig
from hardware.sim.actuators import ActuatorParams, Effects
from hardware.sim.effects_hook import load_hook
from hardware.sim.mujoco_bank import MujocoBank
from hardware.sim.presets import arm_params, motor_params
from hardware.sim.world import GroundTruth, MujocoWorld

GRIPPER_MOTOR = {"piper": "piper_gripper", "damiao": "DM4310", "dynamixel": "XL330-M288",
                 "sim": "piper_gripper"}
# Hz: firmware-law rate of leader worlds. A GELLO leader runs in current mode (its law is K * i, the current
# changes once per driver loop) and is light, so its bank math runs every 2 ms while MuJoCo still integrates
# it at physics_hz (implicit damping + friction slope every physics step); tests/test_twin_speed.py checks the
# motion against the leader stepped every 1 ms. None: the twin's control_hz.
LEADER_CONTROL_HZ = 500.0
REALTIME_SLEEP_S = 0.0005  # s: the real-time thread's nap between catch-ups
REALTIME_MAX_LAG_S = 0.1  # s: a real-time twin further behind than this skips ahead (counted in .overruns)
_SERIAL = itertools.count()


@dataclass
class TwinDevice:
    """One simulated device: its world, bank, emulator and wire endpoint (pty path or CAN channel)."""

    spec: DeviceSpec
    world: MujocoWorld
    bank: MujocoBank
    n_arm: int  # arm joints (the bank may add the gripper after them)
    emulator: object | None = None
    bus: object | None = None
    endpoint: str | None = None


def _effects(spec: dict[str, bool]) -> Effects:
    return replace(Effects(), **spec)


def _servo_models(dev: DeviceSpec) -> tuple[list[str], str]:
    """A Dynamixel leader's servo model per joint and of its trigger, as its config names them."""
    cfg = dev.config
    models = [cfg.model] * len(cfg.ids) if isinstance(cfg.model, str) else list(cfg.model)
    return models, getattr(cfg, "gripper_model", None) or models[-1]


def _device_params(dev: DeviceSpec, arm, with_gripper: bool, effects: Effects) -> ActuatorParams:
    motors, gripper = dev.twin_motors, GRIPPER_MOTOR[dev.driver]
    if dev.driver == "damiao":
        gripper = getattr(dev.config, "gripper_motor", None) or gripper
    if dev.driver == "dynamixel":  # the servos the rig declares (and the emulator reports) are the motors
        servos, gripper = _servo_models(dev)
        motors = motors or servos
    p = arm_params(dev.arm, effects=effects, n=arm.n_joints, motors=motors)
    if with_gripper:
        g = motor_params([gripper], where=f"twin gripper of {dev.name}")
        kw = {f: np.concatenate([getattr(p, f), getattr(g, f)]) for f in ActuatorParams.ARRAY_FIELDS}
        p = replace(p, **kw)
    n = arm.n_joints + int(with_gripper)
    p = p.sized(n)
    for k, v in dev.twin_params.items():
        a = np.asarray(v, dtype=float).reshape(-1)
        if a.size not in (1, arm.n_joints, n):
            raise ConfigError(f"{k} has {a.size} values", where=f"rig {dev.name}.twin.params.{k}",
                              fix=f"give 1 or {arm.n_joints} values")
        getattr(p, k)[: a.size if a.size > 1 else n] = a
    return p


class GripperTransmission:
    """MotorBank view whose last motor is a rotary gripper motor driving the bank's linear finger joint:
    angle theta [rad] = closed_rad + s * x [m], s = (open_rad - closed_rad) / stroke_m, so theta_closed at
    x = 0 and theta_open at the finger's full travel. Forces map by power (F = s * tau), gains by s^2."""

    def __init__(self, bank, closed_rad: float, open_rad: float, stroke_m: float):
        self.bank, self.n, self.g = bank, bank.n, bank.n - 1
        self.c, self.s = float(closed_rad), (float(open_rad) - float(closed_rad)) / float(stroke_m)
        self.torque_constant = bank.torque_constant

    def __getattr__(self, name):  # set_speed etc. pass through
        return getattr(self.bank, name)

    def _split(self, idx, *vals):
        idx = np.atleast_1d(np.asarray(idx, dtype=int))
        return idx, [np.array(np.broadcast_to(np.asarray(v, dtype=float), idx.shape)) for v in vals]

    def read(self):
        r = self.bank.read()
        g, s = self.g, self.s
        r.q[g], r.q_dot[g] = self.c + s * r.q[g], s * r.q_dot[g]
        r.tau_m[g] = r.tau_m[g] / s
        r.current[g] = r.tau_m[g] / self.torque_constant[g]
        return r

    def command_position(self, idx, q) -> None:
        idx, (q,) = self._split(idx, q)
        q[idx == self.g] = (q[idx == self.g] - self.c) / self.s
        self.bank.command_position(idx, q)

    def command_mit(self, idx, q, v, kp, kd, tau_ff) -> None:
        idx, (q, v, kp, kd, tau) = self._split(idx, q, v, kp, kd, tau_ff)
        m, s = idx == self.g, self.s
        q[m], v[m], tau[m] = (q[m] - self.c) / s, v[m] / s, tau[m] * s
        kp[m], kd[m] = kp[m] * s * s, kd[m] * s * s
        self.bank.command_mit(idx, q, v, kp, kd, tau)

    def command_current(self, idx, current_a) -> None:
        idx, (i,) = self._split(idx, current_a)
        i[idx == self.g] *= self.s  # joint force per amp = s * K
        self.bank.command_current(idx, i)

    def enable(self, idx, on: bool) -> None:
        self.bank.enable(idx, on)


class Twin:
    """Simulated rig. Device names are the rig's; see module doc for the stepping order."""

    def __init__(self, rig: Rig, *, effect=None, seed: int | None = None, dynamixel_transport: str = "pty",
                 leader_control_hz: float | None = LEADER_CONTROL_HZ):
        from hardware.arms import load_arm

        self.rig = rig
        self.seed = rig.twin.seed if seed is None else int(seed)
        self.effects = _effects(rig.twin.effects)
        hook_spec = effect if effect is not None else rig.twin.effect
        self.hook = None
        if hook_spec:
            n_check = load_arm(rig.followers[0].arm).n_joints
            self.hook = load_hook(hook_spec, n_check=n_check)
        self.hook_spec = hook_spec
        if dynamixel_transport not in ("pty", "inprocess"):
            raise ConfigError(f"unknown Dynamixel transport {dynamixel_transport!r}", where="Twin",
                              fix="use 'pty' or 'inprocess'")
        self.dynamixel_transport = dynamixel_transport
        # leader worlds take one control tick of leader_every twin ticks (at the end of each block, so at
        # multiples of leader_every * dt they are exactly in time with the followers)
        chz = rig.twin.control_hz
        self.leader_every = max(1, int(chz // leader_control_hz)) if leader_control_hz else 1
        self._every: list[int] = []  # per world: twin ticks per world control tick
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
        self._rt_stop = threading.Event()
        self.overruns = 0
        self.steps = 0
        try:
            for k, dev in enumerate(rig.followers):
                self._add(dev, load_arm(dev.arm), follower=True, seed=self.seed + 101 * k)
            for k, dev in enumerate(rig.leaders):
                self._add(dev, load_arm(dev.arm), follower=False, seed=self.seed + 7919 + 101 * k)
        except BaseException:
            self.close()
            raise

    # -- construction ----------------------------------------------------------------------------------
    def _add(self, dev: DeviceSpec, arm, follower: bool, seed: int) -> None:
        if follower:
            model = mujoco.MjModel.from_xml_path(str(arm.scene_path(self.rig.twin.scene)))
            # resting free objects sleep (no contact work until something touches them); the arm's tree is
            # actuated, so MuJoCo never puts it to sleep
            model.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        else:
            model = mujoco.MjModel.from_xml_path(str(arm.mjcf_path))  # the leader: its own world, no contacts
            model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        model.opt.timestep = self.dt / self.substeps
        world = MujocoWorld(model, name=dev.name)
        cfg = dev.config
        # the gripper motor is the bank's last one when the arm has a gripper joint and the device drives it
        with_gripper = bool(arm.gripper_joints) and (dev.driver in ("piper", "sim")
                                                     or cfg.gripper_id is not None)
        joints = list(arm.joint_names) + ([arm.gripper_joints[0]] if with_gripper else [])
        params = _device_params(dev, arm, with_gripper, self.effects)
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
        td = TwinDevice(spec=dev, world=world, bank=bank, n_arm=arm.n_joints)
        self.worlds.append(world)
        self.devices[dev.name] = td
        if dev.driver == "dynamixel":
            self._add_dynamixel(td, cfg, with_gripper)
        elif dev.driver in ("piper", "damiao"):
            self._add_can(td, cfg, with_gripper, seed)

    def _add_dynamixel(self, td: TwinDevice, cfg, with_gripper: bool) -> None:
        from hardware.dynamixel.emulator import DynamixelEmulator
        from hardware.dynamixel.protocol import OP_MODE_CURRENT

        ids = list(cfg.ids) + ([cfg.gripper_id] if with_gripper else [])
        models, trigger = _servo_models(td.spec)
        if with_gripper:  # the trigger servo: the config's gripper_model, else the last joint's model
            models = models + [trigger]
        signs = [float(s) for s in cfg.signs] + ([1.0] if with_gripper else [])
        offsets = [float(o) for o in cfg.offsets_rad]
        offsets += [float(cfg.gripper_open_rad)] if with_gripper else []
        emu = DynamixelEmulator(td.bank, ids, models, signs=signs, offsets_rad=offsets, return_delay=0,
                                operating_mode=OP_MODE_CURRENT, baud=int(cfg.baud), bank_lock=td.world.lock,
                                seed=self.seed, emulate_return_delay=False,
                                transport=self.dynamixel_transport)
        td.emulator, td.endpoint = emu, emu.port_path
        self._dxl_emus.append(emu)

    def _add_can(self, td: TwinDevice, cfg, with_gripper: bool, seed: int) -> None:
        from hardware.can_bus import open_bus

        channel = f"{self._tag}-{td.spec.name}"
        bus = open_bus(channel, "virtual")
        td.bus, td.endpoint = bus, channel
        if td.spec.driver == "piper":
            from hardware.piper.emulator import PiperEmulator

            lim = td.spec.limits()
            emu = PiperEmulator(bus, td.bank, seed=seed, old_firmware_effort=bool(cfg.firmware_effort_x4),
                                joint_limits_rad=np.stack([lim.q_min, lim.q_max], axis=1))
        else:
            from hardware.damiao.emulator import DamiaoEmulator

            ids = list(cfg.ids) + ([cfg.gripper_id] if with_gripper else [])
            motors = list(cfg.motor) + ([cfg.gripper_motor] if with_gripper else [])
            bank = td.bank
            if with_gripper:  # the gripper motor turns (rad); the MJCF finger slides (m)
                lo, hi = td.world.model.jnt_range[mujoco.mj_name2id(td.world.model, mujoco.mjtObj.mjOBJ_JOINT,
                                                                    bank.joint_names[-1])]
                bank = GripperTransmission(bank, cfg.gripper_closed_rad, cfg.gripper_open_rad, float(hi - lo))
            emu = DamiaoEmulator(bus, bank, ids, motors, master_ids=cfg.master_ids and
                                 (list(cfg.master_ids) + ([cfg.gripper_id + 0x10] if with_gripper else [])),
                                 seed=seed)
        td.emulator = emu
        self._can_emus.append(emu)

    # -- endpoints ---------------------------------------------------------------------------------------
    @property
    def serial_ports(self) -> dict[str, str]:
        return {n: d.endpoint for n, d in self.devices.items() if d.spec.driver == "dynamixel"}

    @property
    def can_channels(self) -> dict[str, str]:
        return {n: d.endpoint for n, d in self.devices.items() if d.spec.driver in ("piper", "damiao")}

    def bank(self, name: str) -> MujocoBank:
        return self.devices[name].bank

    # -- stepping --------------------------------------------------------------------------------------
    def step(self, poll: bool = True) -> None:
        """One physics step of every world, with the CAN emulators' poll before (unless poll is False: the
        caller knows no frame can have arrived) and their emit after."""
        if poll:
            for e in self._can_emus:
                e.poll()
        k = self.steps + 1
        for w, every in zip(self.worlds, self._every):
            if every == 1 or k % every == 0:
                w.step()
        self.t += self.dt
        self.steps = k
        for e in self._can_emus:
            e.emit(self.t)

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
            return n

    def attach(self, clock) -> None:
        """Lockstep: clock.sleep(dt) advances this twin; sim time 0 is the clock's current time."""
        self._t_offset = clock.now() - self.t
        clock.attach(self.advance)

    def start_realtime(self) -> None:
        """A daemon thread steps the physics to wall time (sim time 0 = now)."""
        if self._rt_thread is not None:
            return
        self._rt_stop.clear()
        self._t_offset = time.monotonic() - self.t
        self._rt_thread = threading.Thread(target=self._realtime_loop, name="factr2-twin", daemon=True)
        self._rt_thread.start()

    def _realtime_loop(self) -> None:
        while not self._rt_stop.is_set():
            now = time.monotonic()
            if now - self._t_offset - self.t > REALTIME_MAX_LAG_S:
                self.overruns += 1  # cannot keep up: skip ahead rather than run ever later
                self._t_offset = now - self.t
            self.advance(now)
            time.sleep(REALTIME_SLEEP_S)

    def stop_realtime(self) -> None:
        if self._rt_thread is not None:
            self._rt_stop.set()
            self._rt_thread.join(timeout=2.0)
            self._rt_thread = None

    # -- the virtual world ---------------------------------------------------------------------------------
    def apply_leader_hand_torque(self, tau: np.ndarray, leader: str | None = None) -> None:
        """A virtual operator's hand on a leader's arm joints [N*m] (held until changed)."""
        d = self.devices[leader or self.rig.leaders[0].name]
        d.bank.set_hand_torque(np.asarray(tau, dtype=float).reshape(d.n_arm), d.n_arm)

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
