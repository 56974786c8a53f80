"""Why cap-screw's torque band needs feel (SIMULATED): the lid turned by an ideal hand on its hinge, no arm.

Two ideal operators, neither limited by an arm, a grasp or an estimator:
- blind: turns the lid a fixed angle from where the thread catches (the best single angle, chosen on
  development seeds) and lets go -- all a camera-only operator could do, since the seat is hidden (where the
  thread catches and the gasket's stiffness vary per episode; the lid's height tells the seat to no better
  than the detector's ~2 mm object bias, i.e. ~3 rad of turn at 0.64 mm/rad);
- feeling: turns until the hinge torque it applies has risen `rise_nm` above the running torque it felt
  while the lid ran down, and lets go (the truth of the torque; the scripted demonstrator feels an estimate).

    python -m hardware.sim.tasks.cap_check    # both on 20 evaluation seeds; the blind angle from 10 dev seeds

The hand: a stiff torsion spring (HAND_K_NM_PER_RAD) dragged at RATE_RAD_S, as a wrist turning at a steady
pace. Pure set-up + runs, seeded; used by docs/tasks.md ("cap-screw").
"""

from __future__ import annotations

import mujoco
import numpy as np

from hardware.sim.tasks import cap_screw as C

HAND_K_NM_PER_RAD = 2.0
HAND_D = 0.05  # N*m*s/rad
RATE_RAD_S = 0.5
SETTLE_S = 0.5  # s after letting go before the verdict


def lid_model() -> mujoco.MjModel:
    spec = mujoco.MjSpec()
    spec.compiler.degree = False  # the task gives angles in rad, as the arm scenes do
    spec.option.timestep = 0.001
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.worldbody.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.5, 0.6, 0.025],
                            pos=[0.3, 0, -0.025])
    C.CapScrew().add_objects(spec, None)
    return spec.compile()


def turn_lid(seed: int, angle_rad: float | None = None, rise_nm: float | None = None) -> dict:
    """Turn episode `seed`'s lid (blind: to angle_rad from the thread's start; feeling: until the applied
    torque has risen rise_nm above the running torque), let go; the truth verdict and tau_tight [N*m]."""
    task = C.CapScrew()
    m = lid_model()
    d = mujoco.MjData(m)
    params = task.reset(m, d, np.random.default_rng(seed))
    mujoco.mj_forward(m, d)
    tj = m.joint("cap_turn")
    dt = m.opt.timestep
    ref, held, running, memory = 0.0, True, [], {}
    t_release = None
    limit = (angle_rad if angle_rad is not None else 12.0) / RATE_RAD_S + 2.0
    while d.time < limit + SETTLE_S:
        th, om = d.qpos[tj.qposadr[0]], d.qvel[tj.dofadr[0]]
        tau = 0.0
        if held:
            ref += RATE_RAD_S * dt
            tau = HAND_K_NM_PER_RAD * (ref - th) - HAND_D * om
            if angle_rad is not None and th >= angle_rad:
                held = False
            if rise_nm is not None and d.time > 0.5:
                base = float(np.median(running)) if running else tau
                if tau - base < 0.02:
                    running.append(tau)
                elif tau - base >= rise_nm:
                    held = False
            if not held:
                t_release = d.time
        elif d.time - t_release > SETTLE_S:
            break
        d.qfrc_applied[tj.dofadr[0]] = tau
        mujoco.mj_step(m, d)
        task.detect(task.observe(m, d, params), params, memory)  # latches a strip
    obs = task.observe(m, d, params)
    ok = bool(task.final_ok(obs, params, memory))
    return {"seed": seed, "ok": ok, "tau_tight_nm": float(obs["clamp_n"]) * C.TIGHT_R_M,
            "stripped": bool(memory.get("stripped", False))}


def tight_curve(seed: int, max_rad: float = C.TURNS_TO_SEAT[1] * 2 * np.pi + 1.0) -> tuple:
    """(turn [rad], tau_tight [N*m], strip torque [N*m]) of episode `seed`'s lid turned steadily to max_rad:
    where a blind operator that lets go at a turn would leave it (the released lid self-locks: test)."""
    task = C.CapScrew()
    m = lid_model()
    d = mujoco.MjData(m)
    params = task.reset(m, d, np.random.default_rng(seed))
    mujoco.mj_forward(m, d)
    tj = m.joint("cap_turn")
    ref, turns, tights = 0.0, [], []
    while d.qpos[tj.qposadr[0]] < max_rad and d.time < max_rad / RATE_RAD_S + 3.0:
        ref += RATE_RAD_S * m.opt.timestep
        th, om = d.qpos[tj.qposadr[0]], d.qvel[tj.dofadr[0]]
        d.qfrc_applied[tj.dofadr[0]] = HAND_K_NM_PER_RAD * (ref - th) - HAND_D * om
        mujoco.mj_step(m, d)
        if round(d.time / m.opt.timestep) % 10 == 0:
            turns.append(th)
            tights.append(float(task.observe(m, d, params)["clamp_n"]) * C.TIGHT_R_M)
    peak = np.maximum.accumulate(np.array(tights))  # a strip latches on the way
    return np.array(turns), peak, float(params["_strip_nm"])


def blind_ok(curve, angle_rad: float) -> bool:
    turns, peak, strip = curve
    k = min(int(np.searchsorted(turns, angle_rad)), len(turns) - 1)
    return bool(C.TIGHT_BAND_NM[0] <= peak[k] <= C.TIGHT_BAND_NM[1] and peak[k] <= strip)


def main() -> None:
    dev = [tight_curve(s) for s in range(1000, 1010)]
    angles = np.linspace(C.TURNS_TO_SEAT[0] * 2 * np.pi, C.TURNS_TO_SEAT[1] * 2 * np.pi + 1.0, 200)
    rates = [np.mean([blind_ok(c, a) for c in dev]) for a in angles]
    a = float(angles[int(np.argmax(rates))])
    ev = range(2000, 2020)
    blind = [blind_ok(tight_curve(s), a) for s in ev]
    feel = [turn_lid(s, rise_nm=float(np.mean(C.TIGHT_BAND_NM))) for s in ev]
    tt = np.array([r["tau_tight_nm"] for r in feel])
    print(f"blind, the best fixed turn {a:.2f} rad (dev seeds 1000-1009: {max(rates):.0%}): "
          f"{sum(blind)}/{len(blind)} in band {C.TIGHT_BAND_NM} N*m (seeds 2000-2019)")
    print(f"feeling (truth torque, stops {np.mean(C.TIGHT_BAND_NM):.2f} N*m above running): "
          f"{sum(r['ok'] for r in feel)}/{len(feel)}; tau_tight p10/p50/p90 {np.percentile(tt, 10):.3f}/"
          f"{np.percentile(tt, 50):.3f}/{np.percentile(tt, 90):.3f} N*m; stripped "
          f"{sum(r['stripped'] for r in feel)}")


if __name__ == "__main__":
    main()
