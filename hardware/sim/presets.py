"""Representative actuator parameters per motor type (one source for the twin's numbers).

Sources and reasoning: docs/twin_model.md. Torque constants, current limits and reporting units come from
the vendors' data (hardware-protocols.md). Armature, Coulomb and viscous friction are NOT set here: the bank
takes them from the arm's MJCF (hardware/arms/specs.py is their single source). Stribeck, backlash, ripple,
thermal, noise and firmware loop gains are typical values for low-cost drives of that size, not identified
on a real unit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from hardware.errors import ConfigError
from hardware.sim.actuators import ActuatorParams, Effects

_MOTORS: dict[str, dict] = {
    # AgileX Piper J1-J3: vendor effort factor 1.18125 mN*m per mA; current reported in 1 mA.
    "piper_big": dict(kt=1.18125, stribeck=0.15,
                      stribeck_vel=0.05, smooth_vel=0.005, backlash=0.0035, ripple_amp=0.06, ripple_cycles=36,
                      winding_ohm=0.6, thermal_res=2.5, thermal_tau=600.0, current_noise=0.008,
                      velocity_noise=0.003, current_lsb=0.001, pos_kp=80.0, pos_kd=6.0, pos_ki=160.0,
                      pos_i_max=8.0, pos_vel_max=3.0),
    # Piper J4-J6: 0.95844 mN*m per mA.
    "piper_small": dict(kt=0.95844, stribeck=0.05,
                        stribeck_vel=0.05, smooth_vel=0.005, backlash=0.005, ripple_amp=0.02,
                        ripple_cycles=25,
                        winding_ohm=1.2, thermal_res=4.0, thermal_tau=400.0, current_noise=0.006,
                        velocity_noise=0.003, current_lsb=0.001, pos_kp=25.0, pos_kd=0.8, pos_ki=50.0,
                        pos_i_max=3.0, pos_vel_max=3.0),
    # Piper gripper (prismatic finger, m and N): a stiff position loop; 10 N = the arm spec's gripper_force.
    "piper_gripper": dict(kt=1.0, i_max=10.0, stribeck=0.0,
                          smooth_vel=0.002, backlash=0.0, current_noise=0.0, velocity_noise=0.0,
                          current_lsb=0.001, pos_kp=2000.0, pos_kd=40.0, pos_ki=0.0, pos_i_max=1.0,
                          pos_vel_max=0.1),
    # Damiao DM4340 (40:1): 4.074 N*m/A output side, 27 N*m peak, armature 0.032 (YAM).
    "DM4340": dict(kt=4.074, stribeck=0.15,
                   stribeck_vel=0.05, smooth_vel=0.005, backlash=0.003, ripple_amp=0.08, ripple_cycles=40,
                   winding_ohm=0.9, thermal_res=2.0, thermal_tau=500.0, current_noise=0.005,
                   velocity_noise=0.004, current_lsb=0.0, pos_kp=80.0, pos_kd=5.0, pos_ki=0.0,
                   pos_i_max=1.0, pos_vel_max=8.0),
    # Damiao DM4310 (10:1): 0.945 N*m/A, 7 N*m peak, armature 0.0018.
    "DM4310": dict(kt=0.945, stribeck=0.03,
                   stribeck_vel=0.05, smooth_vel=0.005, backlash=0.004, ripple_amp=0.015, ripple_cycles=10,
                   winding_ohm=1.5, thermal_res=4.0, thermal_tau=300.0, current_noise=0.005,
                   velocity_noise=0.004, current_lsb=0.0, pos_kp=10.0, pos_kd=1.5, pos_ki=0.0,
                   pos_i_max=0.5, pos_vel_max=20.0),
    # Dynamixel X servos: the encoder sits on the output shaft, so the gear play never shows in the sensed
    # position (backlash 0 here). XL330-M288: stall 0.52 N*m at 1.47 A, current limit 1750 mA, 1 mA units.
    "XL330-M288": dict(kt=0.52 / 1.47, stribeck=0.01,
                       stribeck_vel=0.05, smooth_vel=0.005, backlash=0.0, ripple_amp=0.0, winding_ohm=2.5,
                       thermal_res=12.0, thermal_tau=200.0, current_noise=0.004, velocity_noise=0.01,
                       current_lsb=0.001, pos_kp=2.0, pos_kd=0.05, pos_ki=0.0, pos_i_max=0.1,
                       pos_vel_max=6.0),
    # XL330-M077: 0.215 N*m stall, faster gearing.
    "XL330-M077": dict(kt=0.215 / 1.47,
                       stribeck=0.004, stribeck_vel=0.05, smooth_vel=0.005, backlash=0.0, winding_ohm=2.5,
                       thermal_res=12.0, thermal_tau=200.0, current_noise=0.004, velocity_noise=0.01,
                       current_lsb=0.001, pos_kp=0.8, pos_kd=0.02, pos_vel_max=10.0),
    # XC330-M288: 0.93 N*m at 1.8 A, limit 2352 mA.
    "XC330-M288": dict(kt=0.93 / 1.8, stribeck=0.01,
                       stribeck_vel=0.05, smooth_vel=0.005, backlash=0.0, winding_ohm=2.0, thermal_res=10.0,
                       thermal_tau=250.0, current_noise=0.004, velocity_noise=0.01, current_lsb=0.001,
                       pos_kp=3.0, pos_kd=0.06, pos_vel_max=6.0),
    # XM430-W350: 4.1 N*m at 2.3 A, limit 1193 x 2.69 mA.
    "XM430-W350": dict(kt=4.1 / 2.3,
                       stribeck=0.03, stribeck_vel=0.05, smooth_vel=0.005, backlash=0.0, winding_ohm=4.6,
                       thermal_res=8.0, thermal_tau=400.0, current_noise=0.005, velocity_noise=0.01,
                       current_lsb=2.69e-3, pos_kp=10.0, pos_kd=0.3, pos_vel_max=4.0),
    # Franka Panda joints (sim only: no wire protocol here). tau in N*m with kt 1 ("current" = N*m), brakes.
    "panda_big": dict(kt=1.0, stribeck=0.2,
                      stribeck_vel=0.05, smooth_vel=0.005, backlash=0.0, ripple_amp=0.1, ripple_cycles=100,
                      winding_ohm=0.1, thermal_res=1.0, thermal_tau=900.0, current_noise=0.05,
                      velocity_noise=0.002, current_lsb=0.0, pos_kp=600.0, pos_kd=30.0, pos_ki=100.0,
                      pos_i_max=10.0, pos_vel_max=2.0, brake=True),
    "panda_small": dict(kt=1.0, stribeck=0.08,
                        stribeck_vel=0.05, smooth_vel=0.005, backlash=0.0, ripple_amp=0.03, ripple_cycles=100,
                        winding_ohm=0.3, thermal_res=2.0, thermal_tau=600.0, current_noise=0.02,
                        velocity_noise=0.002, current_lsb=0.0, pos_kp=100.0, pos_kd=5.0, pos_ki=20.0,
                        pos_i_max=2.0, pos_vel_max=2.5, brake=True),
    # An imported arm's joints (factr2 arm import): no vendor drive data, so torque is reported in N*m (kt 1)
    # with mid-range effects of the drives above; armature, Coulomb and viscous come from its description.
    # The position loop is given for a GENERIC_REF_TAU_NM joint; arm_params scales it by each joint's tau_max
    # (a 150 N*m UR5 shoulder needs 15x the stiffness to hold itself up). kd / kp = 0.04 s (the loop lags its
    # target by that times the speed); kp 200 / kd 8 damps the UR5 shoulder at about 0.6 (kd 4 let it wind
    # up and fall during a pushed replay; kp 100 sagged).
    # winding_ohm 0: its "current" is torque (kt 1), so no copper loss can be computed from it (1 ohm heated a
    # UR5 shoulder holding 55 N*m by 3 kW: K(T) collapsed and the twin arm fell after ~20 s).
    "generic": dict(kt=1.0, stribeck=0.1, stribeck_vel=0.05, smooth_vel=0.005, backlash=0.002,
                    ripple_amp=0.02, ripple_cycles=50, winding_ohm=0.0, thermal_res=3.0, thermal_tau=500.0,
                    current_noise=0.01, velocity_noise=0.003, current_lsb=0.0, pos_kp=200.0, pos_kd=8.0,
                    pos_ki=400.0, pos_i_max=10.0, pos_vel_max=3.0),
}

ARM_MOTORS: dict[str, list[str]] = {
    "piper": ["piper_big"] * 3 + ["piper_small"] * 3,
    "yam": ["DM4340"] * 3 + ["DM4310"] * 3,
    "panda": ["panda_big"] * 4 + ["panda_small"] * 3,
    "gello_piper": ["XC330-M288"] * 3 + ["XL330-M288"] * 3,  # as hardware/arms/specs.py builds them
    "gello_yam": ["XC330-M288"] * 3 + ["XL330-M288"] * 3,
}


GENERIC_REF_TAU_NM = 10.0  # the joint size the "generic" preset's position loop is written for [N*m]
_POS_GAINS = ("pos_kp", "pos_kd", "pos_ki", "pos_i_max")


def motor_names() -> list[str]:
    return sorted(_MOTORS)


def motor_params(motors: list[str], where: str = "twin") -> ActuatorParams:
    """Stacked per-joint parameters for a list of motor type names (ConfigError on an unknown name)."""
    rows = []
    for m in motors:
        if m not in _MOTORS:
            raise ConfigError(f"unknown motor type {m!r}", where=where,
                              fix=f"use one of {', '.join(motor_names())}")
        rows.append(_MOTORS[m])
    n = len(rows)
    base = ActuatorParams().sized(n)
    kw = {}
    for name in ActuatorParams.ARRAY_FIELDS:
        default = getattr(base, name)
        kw[name] = np.array([float(r.get(name, default[i])) for i, r in enumerate(rows)])
    brake = any(bool(r.get("brake", False)) for r in rows)
    return replace(base, brake=brake, **kw)


def arm_params(arm: str, effects: Effects | None = None, n: int | None = None,
               motors: list[str] | None = None) -> ActuatorParams:
    """Parameters for an arm's joints (the motor list defaults to ARM_MOTORS[arm], else the description's
    factr2.motors: an imported arm's)."""
    names = motors or ARM_MOTORS.get(arm) or _description_motors(arm)
    if names is None:
        raise ConfigError(f"no motor list for arm {arm!r}", where="twin",
                          fix=f"set [followers.twin] motors = [...] in the rig, or use one of "
                              f"{', '.join(sorted(ARM_MOTORS))}")
    if n is not None and len(names) != n:
        raise ConfigError(f"arm {arm!r} has {n} joints but {len(names)} motor types", where="twin",
                          fix="list one motor type per joint")
    p = motor_params(names, where=f"twin motors of {arm}")
    if "generic" in names:
        from hardware.arms import load_arm

        k = np.where(np.array(names) == "generic", load_arm(arm).limits.tau_max / GENERIC_REF_TAU_NM, 1.0)
        p = replace(p, **{g: getattr(p, g) * k for g in _POS_GAINS})
    return replace(p, effects=effects or Effects())


def _description_motors(arm: str) -> list[str] | None:
    from hardware.arms import load_arm

    try:
        return list(load_arm(arm).motors) or None
    except ConfigError:
        return None
