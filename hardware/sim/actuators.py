"""Actuator effects of the simulated motors, as pure functions on per-joint numpy arrays.

The twin's motor model (hardware/sim/mujoco_bank.py calls these once per physics step):

    firmware law (position PD+I with a target ramp / MIT impedance / current)  -> tau_cmd [N*m]
    current i = sat(tau_cmd / K_nom, i_max)                                       [A]
    torque the rotor makes  tau_act = K_nom * kt_scale(T) * i                    [N*m]
    joint load inside the drive  tau_load = friction(v) + ripple(q) + hook(t, q, v)
    joint receives  tau_act - tau_load  (+ gravity, contacts, pushes from MuJoCo)
    firmware reports  current_meas = quantise(i + noise),  tau_m = K_nom * current_meas

so in a static pose the reported torque is gravity + ripple + hook, in slow motion it adds friction, and
none of these loads is external torque. Backlash is a play operator between link and motor-side encoder.
Every effect is switchable (ActuatorParams.effects); numbers per arm are in hardware/sim/presets.py and
docs/twin_model.md. Units: rad, rad/s, N*m, A, degC, s.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

EFFECT_NAMES = ("friction", "stribeck", "backlash", "ripple", "thermal", "kt_temperature", "current_noise",
                "velocity_noise", "quantisation", "saturation")


@dataclass
class Effects:
    """Which actuator effects are simulated (all True = the representative twin; all False = ideal motors
    whose reported torque is exactly what the joint needs)."""

    friction: bool = True  # Coulomb + viscous
    stribeck: bool = True  # extra break-away torque near zero velocity
    backlash: bool = True  # play between motor-side encoder and link
    ripple: bool = True  # position-periodic torque (cogging, gear meshing)
    thermal: bool = True  # winding temperature from i^2 R heating and cooling
    kt_temperature: bool = True  # torque constant falls as the magnets heat
    current_noise: bool = True  # Gaussian noise on the reported current
    velocity_noise: bool = True  # Gaussian noise on the reported velocity
    quantisation: bool = True  # reported current / position in firmware units
    saturation: bool = True  # current limit of the drive

    @classmethod
    def none(cls) -> Effects:
        return cls(**{f.name: False for f in fields(cls)})


def _arr(x, n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(x, dtype=float), (n,)).copy()


@dataclass
class ActuatorParams:
    """Per-joint actuator parameters (arrays of length n after `sized(n)`).

    kt [N*m/A] output-side torque constant the firmware uses; i_max [A] drive current limit;
    armature [kg*m^2] reflected rotor inertia (written into the MuJoCo model); armature, coulomb and viscous
    left NaN are taken from the arm's MJCF (dof_armature, frictionloss, damping: one source of those numbers);
    coulomb [N*m], viscous [N*m*s/rad], stribeck [N*m] extra break-away torque, stribeck_vel [rad/s] its
    decay speed, smooth_vel [rad/s] tanh width that makes friction smooth through zero velocity;
    backlash [rad] total play; ripple_amp [N*m], ripple_cycles [cycles per output revolution],
    ripple_phase [rad]; winding_ohm [Ohm], thermal_res [K/W], thermal_tau [s], ambient [degC],
    kt_temp_coeff [1/K] relative change of kt per K above 25 degC;
    current_noise [A] and velocity_noise [rad/s] standard deviations; current_lsb [A] and position_lsb [rad]
    reporting resolution (0: continuous);
    position loop of the firmware: pos_kp [N*m/rad], pos_kd [N*m*s/rad], pos_ki [N*m/(rad*s)],
    pos_i_max [N*m] integrator clamp, pos_vel_max [rad/s] target ramp speed at 100 %, pos_interp_max_s [s]
    longest command period over which streamed position targets are interpolated (0: each target applies at
    once, a staircase at the command rate);
    brake: joints hold with a brake while disabled (Panda) instead of falling (Piper, Damiao, Dynamixel)."""

    kt: np.ndarray | float = 1.0
    i_max: np.ndarray | float = np.nan  # NaN: the MJCF joint's actuatorfrcrange / kt
    armature: np.ndarray | float = np.nan  # NaN: keep the MJCF's value
    coulomb: np.ndarray | float = np.nan  # NaN: the MJCF joint's frictionloss
    viscous: np.ndarray | float = np.nan  # NaN: the MJCF joint's damping
    stribeck: np.ndarray | float = 0.0
    stribeck_vel: np.ndarray | float = 0.05
    smooth_vel: np.ndarray | float = 0.01
    backlash: np.ndarray | float = 0.0
    ripple_amp: np.ndarray | float = 0.0
    ripple_cycles: np.ndarray | float = 1.0
    ripple_phase: np.ndarray | float = 0.0
    winding_ohm: np.ndarray | float = 1.0
    thermal_res: np.ndarray | float = 3.0
    thermal_tau: np.ndarray | float = 300.0
    ambient: float = 25.0
    kt_temp_coeff: np.ndarray | float = -0.0011
    current_noise: np.ndarray | float = 0.0
    velocity_noise: np.ndarray | float = 0.0
    current_lsb: np.ndarray | float = 0.0
    position_lsb: np.ndarray | float = 0.0
    pos_kp: np.ndarray | float = 50.0
    pos_kd: np.ndarray | float = 1.0
    pos_ki: np.ndarray | float = 0.0
    pos_i_max: np.ndarray | float = 1.0
    pos_vel_max: np.ndarray | float = 3.0
    pos_interp_max_s: np.ndarray | float = 0.05
    brake: bool = False
    effects: Effects = field(default_factory=Effects)

    ARRAY_FIELDS = ("kt", "i_max", "armature", "coulomb", "viscous", "stribeck", "stribeck_vel", "smooth_vel",
                    "backlash", "ripple_amp", "ripple_cycles", "ripple_phase", "winding_ohm", "thermal_res",
                    "thermal_tau", "kt_temp_coeff", "current_noise", "velocity_noise", "current_lsb",
                    "position_lsb", "pos_kp", "pos_kd", "pos_ki", "pos_i_max", "pos_vel_max",
                    "pos_interp_max_s")

    def sized(self, n: int) -> ActuatorParams:
        """A copy with every per-joint field broadcast to shape (n,); raises ValueError on a wrong length."""
        kw = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in self.ARRAY_FIELDS:
                a = np.asarray(v, dtype=float).reshape(-1)
                if a.size not in (1, n):
                    raise ValueError(f"actuator parameter {f.name} has {a.size} entries, expected 1 or {n}")
                v = _arr(a if a.size == n else a[0], n)
            kw[f.name] = v
        return ActuatorParams(**kw)

    def subset(self, idx) -> ActuatorParams:
        """Parameters of the joints `idx` (arrays must be sized)."""
        kw = {f.name: (getattr(self, f.name)[idx] if f.name in self.ARRAY_FIELDS else getattr(self, f.name))
              for f in fields(self)}
        return ActuatorParams(**kw)


# -- friction --------------------------------------------------------------------------------------
def friction_torque(v: np.ndarray, coulomb: np.ndarray, viscous: np.ndarray, stribeck: np.ndarray,
                    stribeck_vel: np.ndarray, smooth_vel: np.ndarray) -> np.ndarray:
    """Friction load [N*m] (same sign as v [rad/s]):
    (Fc + Fs exp(-(v/vs)^2)) tanh(v/v_eps) + Fv v. Smooth through zero (no switching)."""
    return (coulomb + stribeck * np.exp(-(v / stribeck_vel) ** 2)) * np.tanh(v / smooth_vel) + viscous * v


def friction_slope(v: np.ndarray, coulomb: np.ndarray, viscous: np.ndarray, stribeck: np.ndarray,
                   stribeck_vel: np.ndarray, smooth_vel: np.ndarray) -> np.ndarray:
    """d friction / dv [N*m*s/rad] (may be negative in the Stribeck droop)."""
    e = np.exp(-(v / stribeck_vel) ** 2)
    th = np.tanh(v / smooth_vel)
    return ((coulomb + stribeck * e) * (1.0 - th * th) / smooth_vel
            - 2.0 * stribeck * e * v / (stribeck_vel * stribeck_vel) * th + viscous)


def friction_constants(p: ActuatorParams) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint constants linearised_friction needs: (1 / v_eps, -1 / vs^2) (computed once per bank)."""
    return 1.0 / p.smooth_vel, -1.0 / (p.stribeck_vel * p.stribeck_vel)


def linearised_friction(v: np.ndarray, p: ActuatorParams,
                        k: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Friction split for a linearly implicit integrator: (damping D >= 0 [N*m*s/rad], offset [N*m]) with
    friction(v') ~= offset + D v' near v. D is the slope of the smoothed Coulomb + viscous part (always
    >= 0); the integrator treats it implicitly, so the stiff slope at v = 0 stays stable at 1 kHz. The
    Stribeck droop (negative slope) stays explicit. Equals friction_torque at v' = v."""
    ef = p.effects
    if not ef.friction:
        z = np.zeros_like(v)
        return z, z
    inv_eps, neg_inv_vs2 = friction_constants(p) if k is None else k
    # in place where possible: this runs at every control tick of every bank
    x = v * inv_eps
    th = np.tanh(x)
    big_f = p.coulomb
    if ef.stribeck:
        big_f = v * v
        big_f *= neg_inv_vs2
        np.exp(big_f, out=big_f)
        big_f *= p.stribeck
        big_f += p.coulomb  # Fc + Fs exp(-(v/vs)^2)
    bs = th * th
    np.subtract(1.0, bs, out=bs)
    bs *= big_f  # big_f (1 - th^2)
    damp = bs * inv_eps  # slope of the smoothed Coulomb part, >= 0
    damp += p.viscous
    # friction(v) = big_f th + Fv v = (big_f th - D_c v) + (D_c + Fv) v, D_c = bs / v_eps, so D_c v = bs x
    np.multiply(big_f, th, out=th)
    x *= bs
    th -= x
    return damp, th


# -- transmission ----------------------------------------------------------------------------------
def backlash_play(q_link: np.ndarray, theta_prev: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Motor-side position [rad] after a play (backlash) operator of total width [rad]: the motor side moves
    only when the link pushes it from one flank of the gap. Unconditionally stable (no stiff contact)."""
    h = 0.5 * width
    return np.minimum(np.maximum(theta_prev, q_link - h), q_link + h)


def ripple_torque(q: np.ndarray, amp: np.ndarray, cycles: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """Position-periodic torque [N*m] (cogging / gear meshing), `cycles` per output revolution."""
    return amp * np.sin(cycles * q + phase)


# -- firmware control laws -------------------------------------------------------------------------
def ramp_target(q_ramp: np.ndarray, q_goal: np.ndarray, v_max: np.ndarray, dt: float) -> np.ndarray:
    """Move the firmware's internal setpoint [rad] towards the goal at most v_max [rad/s] per second."""
    step = v_max * dt
    return q_ramp + np.minimum(np.maximum(q_goal - q_ramp, -step), step)


def position_loop(q_set: np.ndarray, q: np.ndarray, v: np.ndarray, integ: np.ndarray, kp: np.ndarray,
                  kd: np.ndarray, ki: np.ndarray, i_max: np.ndarray,
                  dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Vendor-like joint position loop: PD on the motor-side position plus a clamped integrator.
    Returns (torque request [N*m], new integrator state [N*m])."""
    err = q_set - q
    integ = np.minimum(np.maximum(integ + ki * err * dt, -i_max), i_max)
    return kp * err - kd * v + integ, integ


def mit_torque(q: np.ndarray, v: np.ndarray, q_d: np.ndarray, v_d: np.ndarray, kp: np.ndarray,
               kd: np.ndarray, tau_ff: np.ndarray) -> np.ndarray:
    """Damiao/Piper MIT law [N*m]: kp (q_d - q) + kd (v_d - v) + tau_ff."""
    return kp * (q_d - q) + kd * (v_d - v) + tau_ff


def clamp_(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """x <- min(max(x, lo), hi) in place; returns x (the hot loops' clamp without temporaries)."""
    np.maximum(x, lo, out=x)
    return np.minimum(x, hi, out=x)


def saturate_current(i: np.ndarray, i_max: np.ndarray, on: bool = True) -> np.ndarray:
    """Drive current limit [A]."""
    return np.minimum(np.maximum(i, -i_max), i_max) if on else i


# -- sensing and heating ---------------------------------------------------------------------------
def quantise(x: np.ndarray, lsb: np.ndarray) -> np.ndarray:
    """Round to multiples of lsb (lsb <= 0: unchanged)."""
    safe = np.where(lsb > 0, lsb, 1.0)
    return np.where(lsb > 0, np.rint(x / safe) * safe, x)


def measured_current(i: np.ndarray, noise_a: np.ndarray, lsb_a: np.ndarray, rng: np.random.Generator | None,
                     noise: bool, quant: bool) -> np.ndarray:
    """What the drive reports [A]: true current plus Gaussian noise, in firmware units."""
    out = i + noise_a * rng.standard_normal(i.shape) if (noise and rng is not None) else i
    return quantise(out, lsb_a) if quant else out


def thermal_step(temp: np.ndarray, i: np.ndarray, r_ohm: np.ndarray, r_th: np.ndarray, tau_th: np.ndarray,
                 ambient: float, dt: float) -> np.ndarray:
    """Winding temperature [degC] after dt: first order, steady rise i^2 R R_th, time constant tau_th.
    Exact discretisation of the linear ODE, stable for any dt."""
    t_ss = ambient + i * i * r_ohm * r_th
    a = np.exp(-dt / tau_th)
    return t_ss + (temp - t_ss) * a


def kt_scale(temp: np.ndarray, coeff: np.ndarray) -> np.ndarray:
    """Actual / nominal torque constant at winding temperature temp [degC] (magnets weaken when hot)."""
    return 1.0 + coeff * (temp - 25.0)
