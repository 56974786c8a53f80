"""MotorBank on a MuJoCo model: firmware control laws + actuator effects + rigid-body physics, no gravcomp.

A MujocoWorld (hardware/sim/world.py) owns the MjModel/MjData; each control tick (1 ms by default) every
bank computes its motor torques from the current command modes and writes them, minus the drive's internal
loads (friction, ripple, the undeclared hook), into qfrc_applied; the firmware's damping and friction's
slope go into dof_damping so MuJoCo integrates them implicitly; then mj_step. Streamed position targets are
interpolated as servo drives do (hardware/sim/targets.py). Gravity is never compensated inside the sim: the
motors carry it. read() returns what the firmware reports (motor-side position after
backlash, noisy velocity, quantised noisy current, tau_m = K * current). Ground truth lives in world.py.
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from typing import Protocol

import mujoco
import numpy as np

from hardware.sim import actuators as act
from hardware.sim.bank_joints import as_slice, bind_joints
from hardware.sim.effects_hook import HookFn, call_hook
from hardware.sim.motors import MODE_CURRENT, MODE_DISABLED, MODE_MIT, MODE_POSITION, MotorReading
from hardware.sim.targets import TargetPath

BRAKE_KP = 2000.0  # N*m/rad: holding brake of a disabled joint (arms with brakes only)
BRAKE_KD = 50.0  # N*m*s/rad
NOISE_BLOCK = 1024  # physics steps per block of pre-drawn sensor noise
THERMAL_EVERY = 10  # physics steps between winding-temperature updates

class BankWorld(Protocol):
    """What a bank reads of the world that steps it (world.py's MujocoWorld). A contract here, so that the
    world imports its banks and the banks do not import the world (no circle)."""

    model: mujoco.MjModel
    data: mujoco.MjData
    lock: AbstractContextManager  # held by the world while it steps; a bank takes it to read or command
    dt: float  # the control tick (the firmware laws' period) [s]
    steps: int  # control ticks stepped so far (the sensor noise's clock)


class MujocoBank:
    """Motors on `joints` (names of 1-dof hinge/slide joints) of a world (BankWorld). Implements MotorBank."""

    def __init__(self, world: BankWorld, joints: list[str], params: act.ActuatorParams, *,
                 name: str = "bank", seed: int = 0, hook: HookFn | None = None):
        self.world, self.name, self.n = world, name, len(joints)
        self.joint_names = list(joints)
        self.p, self.qadr, self.dadr = bind_joints(world.model, joints, params, name)
        self.torque_constant = self.p.kt.copy()
        self.seed = int(seed)
        self.hook = hook
        self.hook_n = self.n  # the hook sees and loads the first hook_n joints (the arm, not the gripper)
        self.hook_errors = 0
        self.hook_last_error: str | None = None
        d = world.data
        q0 = d.qpos[self.qadr].copy()
        self.mode = np.full(self.n, MODE_DISABLED, dtype=int)
        self._sel_cache: dict[tuple[int, ...], slice | np.ndarray] = {}
        self._masks()
        self.q_set, self.integ = q0.copy(), np.zeros(self.n)
        self.targets = TargetPath(q0, self.p.pos_interp_max_s)  # streamed targets, interpolated
        self.q_d, self.v_d = q0.copy(), np.zeros(self.n)
        self.kp, self.kd, self.tau_ff = np.zeros(self.n), np.zeros(self.n), np.zeros(self.n)
        self.i_cmd = np.zeros(self.n)
        self.q_brake = q0.copy()
        self.theta = q0.copy()  # motor-side (encoder) position [rad]
        self.temp = np.full(self.n, float(self.p.ambient))
        self.tau_ripple = np.zeros(self.n)  # position-periodic load [N*m]
        self.tau_hook = np.zeros(self.n)  # undeclared-effect load [N*m]
        self._fric = (np.zeros(self.n), np.zeros(self.n))
        self.tau_e, self.kd_eff = np.zeros(self.n), np.zeros(self.n)  # firmware torque split (see _apply)
        self.tau_hand = np.zeros(self.n)  # operator's hand on the joints (external) [N*m]
        self._hand_imp: tuple | None = None  # the hand as an impedance (set_hand_impedance), else None
        self.vel_scale = np.ones(self.n)  # firmware speed setting (0..1] scaling pos_vel_max
        # per-step constants (the hot loop avoids fancy indexing and recomputation)
        self.qsl, self.dsl = as_slice(self.qadr), as_slice(self.dadr)
        contiguous = isinstance(self.qsl, slice) and isinstance(self.dsl, slice)
        self._views = (d.qpos[self.qsl], d.qvel[self.dsl], d.qfrc_applied[self.dsl],
                       world.model.dof_damping[self.dsl]) if contiguous else None  # see _joint_state
        self._zeros = np.zeros(self.n)
        self._half_play = 0.5 * self.p.backlash
        self._has_play = bool(np.any(self.p.backlash > 0))
        self._inv_kt = 1.0 / self.p.kt
        self._tau_lim = self.p.i_max * self.p.kt
        self._neg_tau_lim = -self._tau_lim
        self._neg_i_max = -self.p.pos_i_max
        self._has_ki = bool(np.any(self.p.pos_ki > 0))
        self._has_ripple = bool(np.any(self.p.ripple_amp != 0))
        self._fric_k = act.friction_constants(self.p)
        self._kt_scale = np.ones(self.n)
        self.set_control_dt(world.dt)
        self._thermal_count = 0
        self._pos_lsb_on = bool(np.any(self.p.position_lsb > 0))
        self._cur_lsb_on = bool(np.any(self.p.current_lsb > 0))
        self._cur_lsb_all = bool(np.all(self.p.current_lsb > 0))
        self._cur_lsb = self.p.current_lsb.copy()
        self._inv_cur_lsb = 1.0 / np.where(self._cur_lsb > 0, self._cur_lsb, 1.0)
        self._noise_buf, self._noise_block = np.zeros((NOISE_BLOCK, 2, self.n)), -1

    # -- MotorBank ---------------------------------------------------------------------------------------
    def read(self) -> MotorReading:
        p, ef = self.p, self.p.effects
        with self.world.lock:  # fresh temporaries updated in place, same operation order (see _apply)
            q, v = self._joint_state()
            if ef.backlash and self._has_play:
                theta = np.maximum(self.theta, q - self._half_play)
                np.minimum(theta, q + self._half_play, out=theta)
            else:
                theta = q.copy()
            if ef.quantisation and self._pos_lsb_on:
                theta = act.quantise(theta, p.position_lsb)
            cur = self.kd_eff * v  # self.current: (tau_e - kd_eff * v) / kt
            np.subtract(self.tau_e, cur, out=cur)
            cur *= self._inv_kt
            v = v.copy()
            if ef.velocity_noise or ef.current_noise:
                z = self._noise()
                if ef.velocity_noise:
                    v += p.velocity_noise * z[0]
                if ef.current_noise:
                    cur += p.current_noise * z[1]
            if ef.quantisation and self._cur_lsb_on:
                cur = np.rint(cur * self._inv_cur_lsb) * self._cur_lsb if self._cur_lsb_all \
                    else act.quantise(cur, p.current_lsb)
            return MotorReading(t=float(self.world.data.time), q=theta, q_dot=v, current=cur,
                                tau_m=p.kt * cur, temperature=self.temp.copy(), enabled=self._enabled.copy())

    def _noise(self) -> np.ndarray:
        """Two standard-normal rows (velocity, current) for the current physics step. A function of (seed,
        step) only, so every read within a step agrees and the values do not depend on how often or from
        which thread the emulators read (lockstep runs stay deterministic)."""
        k = self.world.steps
        block, i = divmod(k, NOISE_BLOCK)
        if block != self._noise_block:
            rng = np.random.default_rng([self.seed, block])
            self._noise_buf, self._noise_block = rng.standard_normal((NOISE_BLOCK, 2, self.n)), block
        return self._noise_buf[i]

    def _sel(self, idx) -> tuple[slice | np.ndarray, tuple[int, ...]]:
        """(selector, joint tuple) for joint indices idx: a slice for a contiguous run (numpy views, cheaper
        than fancy indexing on every command), else the index array. Cached per index set; an index outside
        the bank raises IndexError as fancy indexing would."""
        key = tuple((idx if type(idx) is np.ndarray and idx.ndim == 1 else np.atleast_1d(idx)).tolist())
        sel = self._sel_cache.get(key)
        if sel is None:
            a = np.asarray(key, dtype=int)
            if a.size and (a.min() < 0 or a.max() >= self.n):
                raise IndexError(f"bank {self.name}: joint index out of range in {list(key)}")
            run = a.size > 0 and np.array_equal(a, np.arange(a[0], a[0] + a.size))
            sel = self._sel_cache[key] = slice(int(a[0]), int(a[0]) + a.size) if run else a
        return sel, key

    def command_position(self, idx, q) -> None:
        with self.world.lock:
            sel, key = self._sel(idx)
            modes = self._mode_list
            fresh = () if self._all_in(MODE_POSITION, key) else [j for j in key if modes[j] != MODE_POSITION]
            if fresh:  # bumpless switch into position mode: setpoint and target at the motor, no integral
                self.integ[fresh] = 0.0
                self._reset_targets(fresh, self.theta[fresh], forget=True)
            self.targets.new(sel, q, float(self.world.data.time))
            self._set_mode(sel, MODE_POSITION, key)

    def _reset_targets(self, idx, q, forget: bool = False) -> None:
        """Targets (and setpoints) of joints idx jump to q [rad]: no interpolation in progress."""
        self.targets.reset(idx, q, forget)
        self.q_set[idx] = q

    def command_mit(self, idx, q, v, kp, kd, tau_ff) -> None:
        with self.world.lock:
            sel, key = self._sel(idx)
            self.q_d[sel], self.v_d[sel], self.kp[sel], self.kd[sel], self.tau_ff[sel] = q, v, kp, kd, tau_ff
            self._set_mode(sel, MODE_MIT, key)

    def command_current(self, idx, current_a) -> None:
        with self.world.lock:
            sel, key = self._sel(idx)
            self.i_cmd[sel] = current_a
            self._set_mode(sel, MODE_CURRENT, key)

    def _set_mode(self, sel, mode: int, key: tuple[int, ...]) -> None:
        """Mode of joints sel (key: the same joints as a tuple); the masks are rebuilt only when a mode
        changes (commands come every tick)."""
        if not self._all_in(mode, key):
            self.mode[sel] = mode
            self._masks()

    def _all_in(self, mode: int, key: tuple[int, ...]) -> bool:
        """Joints key are all in `mode`; the answer is kept until a mode changes (the same joints are
        commanded in the same mode every tick: spares the per-joint checks)."""
        ck = (mode, key)
        if ck in self._in_mode:
            return True
        ok = all(self._mode_list[j] == mode for j in key)
        if ok:
            self._in_mode.add(ck)
        return ok

    def enable(self, idx, on: bool) -> None:
        """on: disabled joints start holding their current position; off: torque off (brake if fitted)."""
        with self.world.lock:
            idx = np.atleast_1d(np.asarray(idx, dtype=int))
            if on:
                off = idx[self.mode[idx] == MODE_DISABLED]
                self._reset_targets(off, self.theta[off])
                self.integ[off] = 0.0
                self.mode[off] = MODE_POSITION
            else:
                self.mode[idx] = MODE_DISABLED
                self.q_brake[idx] = self.world.data.qpos[self.qadr[idx]]
            self._masks()

    def set_speed(self, idx, fraction: float) -> None:
        """Firmware speed setting (Piper 0x151 speed %): scales the position loop's target ramp."""
        with self.world.lock:
            self.vel_scale[np.asarray(idx, dtype=int)] = float(np.clip(fraction, 0.01, 1.0))
            self.set_control_dt(self._ctrl_dt)

    def set_hand_torque(self, tau, n: int | None = None) -> None:
        """An operator's hand on the first n joints [N*m] (external to the motors; held until changed)."""
        with self.world.lock:
            self._hand_imp = None
            self.tau_hand[: self.n if n is None else n] = tau

    def set_hand_impedance(self, q_ref, qd_ref, k, d, tau_max, n: int) -> None:
        """An operator's hand as an impedance on the first n joints: tau = clip(k (q_ref - q) + d (qd_ref -
        q_dot), +-tau_max) [N*m], computed at every firmware step from the true joints (held references
        until changed). A hand is not sampled by the teleop loop: a torque computed per loop tick and held
        through a late tick (tens of ms on a slow core while the twin catches up) flung the light GELLO
        wrist (issue #53)."""
        with self.world.lock:
            self._hand_imp = (np.array(q_ref, float), np.array(qd_ref, float), np.asarray(k, float),
                              np.asarray(d, float), np.asarray(tau_max, float), int(n))

    def set_control_dt(self, dt: float) -> None:
        """Period of the firmware law [s] (= the physics step unless the twin decimates control)."""
        self._ctrl_dt = float(dt)
        self._ramp_step = self.p.pos_vel_max * self.vel_scale * dt
        self._neg_ramp_step = -self._ramp_step
        self._ki_dt = self.p.pos_ki * dt

    # -- stepping (called by MujocoWorld with its lock held) --------------------------------------------
    def _masks(self) -> None:
        """Per-mode masks, rebuilt only when a mode changes. Float masks (1.0 where a joint is in that mode)
        select each law's share with one multiply instead of np.where (a bank often mixes modes: a disabled
        gripper or trigger motor next to the arm's joints)."""
        m = self.mode
        self._mode_list = m.tolist()
        self._in_mode: set[tuple[int, tuple[int, ...]]] = set()  # (mode, joints) known all in it (_all_in)
        self._pos, self._mit, self._cur = m == MODE_POSITION, m == MODE_MIT, m == MODE_CURRENT
        self._off = m == MODE_DISABLED
        self._enabled = ~self._off  # read()'s enabled
        self._any = tuple(bool(x.any()) for x in (self._pos, self._mit, self._cur, self._off))
        self._uniform = bool(np.all(m == m[0]))
        self._fpos, self._fmit, self._fcur = (x.astype(float) for x in (self._pos, self._mit, self._cur))
        self._kd_pos = self.p.pos_kd * self._fpos

    def _apply(self, t: float, dt: float) -> None:
        """Compute this control tick's motor torques and write them into the world.

        The firmware law is split as tau = tau_e - kd_eff * v: the stiffness/feed-forward part tau_e is held
        over the tick, the damping kd_eff (with the friction slope) goes into dof_damping so MuJoCo
        integrates it implicitly -- stable for any MIT kd the safety layer allows. A joint whose torque would
        exceed the drive limit is saturated explicitly instead (kd_eff = 0 there).
        Speed: on 7-vectors each numpy call costs far more than its arithmetic, so temporaries are updated in
        place and constants precomputed, each operation in the plain formula's order (bit-identical)."""
        p, ef = self.p, self.p.effects
        q, v = self._joint_state()
        if ef.backlash and self._has_play:
            th = np.maximum(self.theta, q - self._half_play)
            self.theta = th = np.minimum(th, q + self._half_play, out=th)
        else:
            self.theta = th = q
        any_pos, any_mit, any_cur, any_off = self._any
        uniform = self._uniform
        tau_e, kd = self._zeros, self._zeros
        if any_pos:
            step = self.targets.at(t) - self.q_set
            q_set = self.q_set = self.q_set + act.clamp_(step, self._neg_ramp_step, self._ramp_step)
            err = q_set - th
            tau_e = p.pos_kp * err
            if self._has_ki:
                integ = self._ki_dt * err
                integ += self.integ
                act.clamp_(integ, self._neg_i_max, p.pos_i_max)
                if not uniform:
                    integ *= self._fpos
                self.integ = integ
                tau_e += integ
            if not uniform:
                tau_e *= self._fpos
            kd = self._kd_pos
        if any_mit:
            tm = self.kp * (self.q_d - th) + self.kd * self.v_d + self.tau_ff
            tau_e, kd = (tm, self.kd) if uniform else (tau_e + tm * self._fmit, kd + self.kd * self._fmit)
        if any_cur:
            tc = self.i_cmd * p.kt
            tau_e = tc if uniform else tau_e + tc * self._fcur
        no_kd = not (any_pos or any_mit)  # current mode / disabled only: no implicit damping from the law
        if ef.saturation:
            if no_kd:  # the request is tau_e itself: a plain clamp
                tau_e = act.clamp_(tau_e.copy(), self._neg_tau_lim, self._tau_lim)
            else:
                est = kd * v
                np.subtract(tau_e, est, out=est)
                lim = act.clamp_(est.copy(), self._neg_tau_lim, self._tau_lim)
                sat = lim != est
                if np.count_nonzero(sat):  # (ndarray.any costs ~3 us on a 7-vector here)
                    np.copyto(tau_e, lim, where=sat)  # tau_e is this tick's own array here; kd may not be
                    kd = kd.copy()
                    kd[sat] = 0.0
        self.tau_e, self.kd_eff = tau_e, kd
        ks = self._kt_scale
        net = ks * tau_e
        if self._hand_imp is not None:
            qr, qdr, kh, dh, tmax, nh = self._hand_imp
            th = kh * (qr - q[:nh]) + dh * (qdr - v[:nh])
            np.clip(th, -tmax, tmax, out=th)
            self.tau_hand[:nh] = th
        net += self.tau_hand
        if ef.ripple and self._has_ripple:
            r = p.ripple_cycles * q
            r += p.ripple_phase
            np.sin(r, out=r)
            r *= p.ripple_amp
            self.tau_ripple = r
            net -= r
        if self.hook is not None:
            self.tau_hook = self._call_hook(t, q, v)
            net -= self.tau_hook
        damp, f0 = self._fric = act.linearised_friction(v, p, self._fric_k)  # kept apart: tau_friction
        net -= f0
        if not no_kd:
            damp = ks * kd + damp
        if p.brake and any_off:
            net = net - np.where(self._off, BRAKE_KP * (q - self.q_brake), 0.0)
            damp = damp + np.where(self._off, BRAKE_KD, 0.0)
        self._write(net, damp)

    def _joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """(qpos, qvel) of the bank's joints: the cached views (MjData keeps its buffers) when contiguous."""
        d = self.world.data
        return self._views[:2] if self._views else (d.qpos[self.qsl], d.qvel[self.dsl])

    def _write(self, net: np.ndarray, damp: np.ndarray) -> None:
        """net torque into qfrc_applied [N*m], implicit damping into dof_damping [N*m*s/rad]."""
        if self._views:
            self._views[2][:], self._views[3][:] = net, damp
        else:
            self.world.data.qfrc_applied[self.dsl], self.world.model.dof_damping[self.dsl] = net, damp

    @property
    def tau_cmd(self) -> np.ndarray:
        """Torque the firmware asks of the motor now [N*m] (implicit damping at the current velocity)."""
        return self.tau_e - self.kd_eff * self.world.data.qvel[self.dsl]

    @property
    def current(self) -> np.ndarray:
        """True winding current [A]."""
        return self.tau_cmd * self._inv_kt

    @property
    def tau_act(self) -> np.ndarray:
        """Torque the rotors make [N*m] (the torque constant drifts with temperature)."""
        return self._kt_scale * self.tau_cmd

    def _after_step(self, dt: float) -> None:
        if self.p.effects.thermal:
            self._thermal_count += 1
            if self._thermal_count >= THERMAL_EVERY:  # exact discretisation: slow state, updated at 100 Hz
                self.temp = act.thermal_step(self.temp, self.current, self.p.winding_ohm, self.p.thermal_res,
                                             self.p.thermal_tau, self.p.ambient, dt * self._thermal_count)
                self._thermal_count = 0
                if self.p.effects.kt_temperature:
                    self._kt_scale = act.kt_scale(self.temp, self.p.kt_temp_coeff)

    @property
    def tau_friction(self) -> np.ndarray:
        """Friction load of the last step [N*m] (at its end velocity, as the implicit integrator used)."""
        damp, f0 = self._fric
        return f0 + damp * self.world.data.qvel[self.dsl]

    @property
    def tau_load(self) -> np.ndarray:
        """Ripple + hook load of the last step [N*m]."""
        return self.tau_ripple + self.tau_hook

    def _call_hook(self, t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        tau, err = call_hook(self.hook, t, q, v, self.hook_n, self.n)
        if err is not None:
            self.hook_errors, self.hook_last_error = self.hook_errors + 1, err
        return tau

    def true_state(self) -> tuple[np.ndarray, np.ndarray]:
        d = self.world.data
        return d.qpos[self.qadr].copy(), d.qvel[self.dadr].copy()
