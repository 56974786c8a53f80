"""Twin logs for closing the diagnosis loop: free motion on `sim-piper` in lockstep, one effect injected.

    paths = generate("out/", TWIN_CASES["position_periodic"], seconds=60, heldout_seconds=30)
    factr2 diagnose out/train.npz --heldout out/heldout.npz --arm piper --out diag/

SIMULATED data. The follower runs through its real driver (Piper CAN protocol on a python-can virtual bus,
safety layer, firmware position loop) and calibration.next.collect.collect_free_motion records the plain log
(t, q, qd, q_cmd, tau_m [N*m], current [A]). The injected effect goes in ONLY through the twin's
undeclared-effect hook f(t, q, q_dot) -> tau [N*m] (hardware/sim/effects_hook.py): it is a load inside the
drive, so the reported torque shows it, and no configuration an estimator reads mentions it.

Which twin effects stay on (`twin_effects`): the family runs switch the twin's own mechanical effects off
(friction, Stribeck, backlash, ripple, heating and K(T)) and keep the sensor effects on (current and
velocity noise, firmware quantisation, current limit): then each run contains exactly one undeclared effect
on top of the arm's nominal rigid body, and "right family, right joint" is well defined. `TWIN_DEFAULTS`
(every switch on, as in the shipped rig) is the realistic arm: there diagnosis must first explain the twin's
own friction / ripple before anything else.

First pass: even with its mechanical effects off the twin is not the rigid model (firmware position loop,
implicitly integrated damping, feedback timing), so `first_pass(diagnose_logs(no-injection logs))` gives the
twin's own small terms; they are `declared` when the injected runs (same trajectories) are diagnosed, and the
injected effect must be found on top. A no-injection check on fresh trajectories must then add nothing.

Families and how each is injected (joint index 0-based, amplitudes in N*m):
  coulomb/viscous/stribeck friction, position_periodic, backlash-like direction memory (a play operator on
  q, evaluated by a stateful hook), position_spring, drift (in time), current_offset (constant), coupling
  (another joint's velocity), delay and torque_constant_scale (both through the arm's rigid torque computed
  inside the hook, see _RigidLoad: a K error multiplies the motor's own torque, which f(t, q, qd) cannot
  see; in free motion the motor's torque is about the rigid torque, so (s - 1) * rnea has that signature).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from hardware.reasons import render

MECHANICAL = ("friction", "stribeck", "backlash", "ripple", "thermal", "kt_temperature")
CLEAN_EFFECTS = {k: False for k in MECHANICAL}  # sensor effects (noise, quantisation, saturation) stay on
TWIN_DEFAULTS: dict[str, bool] = {}  # the rig's own switches (all on)
N_JOINTS = 6  # AgileX Piper arm joints


@dataclass
class TwinCase:
    """One injected effect: `make()` returns a fresh hook f(t, q, qd) -> tau [N*m] (hooks may hold state)."""

    family: str  # the diagnosis family the case should be traced to ("none": nothing injected)
    joint: int | None
    make: object  # () -> hook or None
    note: str = ""
    params: dict = field(default_factory=dict)
    prior_weight: float | None = None  # the rigid part's pull toward the description (None: piper_basis's)


def _one(j: int, fn):
    def hook(t, q, qd):
        tau = np.zeros(N_JOINTS)
        tau[j] = fn(t, np.asarray(q, float), np.asarray(qd, float))
        return tau
    return hook


def _coulomb(j, fc):
    return lambda: _one(j, lambda t, q, qd: fc * np.tanh(qd[j] / 0.01))


def _viscous(j, fv):
    return lambda: _one(j, lambda t, q, qd: fv * qd[j])


def _stribeck(j, fs, vs):
    return lambda: _one(j, lambda t, q, qd: fs * np.exp(-(qd[j] / vs) ** 2) * np.tanh(qd[j] / 0.01))


def _periodic(j, amp, period, phase):
    return lambda: _one(j, lambda t, q, qd: amp * np.sin(2 * np.pi * q[j] / period + phase))


def _spring(j, k, q0):
    return lambda: _one(j, lambda t, q, qd: k * (q[j] - q0))


def _drift(j, rate):
    return lambda: _one(j, lambda t, q, qd: rate * t)


def _offset(j, c):
    return lambda: _one(j, lambda t, q, qd: c)


def _coupling(j, src, fv):
    return lambda: _one(j, lambda t, q, qd: fv * qd[src])


def _backlash(j, amp, width):
    """Direction memory: amp * sign of a play operator of width `width` [rad] on q_j (keeps its sign at
    standstill, unlike Coulomb friction)."""
    def make():
        state = {"p": None}

        def f(t, q, qd):
            if state["p"] is None:
                state["p"] = q[j]
            state["p"] = min(max(state["p"], q[j] - width / 2), q[j] + width / 2)
            return amp * np.tanh((q[j] - state["p"]) / (0.25 * width))
        return _one(j, f)
    return make


class _RigidLoad:
    """A hook built on the arm's own rigid-body torque without the inertial part, r = rnea(q, qd, 0) [N*m]
    (gravity + Coriolis) on joint j. The inertial part is left out on purpose: a load from a differentiated
    acceleration, fed back through the firmware position loop, made the arm diverge within 0.6 s. mode
    "scale": (s - 1) * r -- in free motion the drive then reports about s x the rigid torque, the signature of
    a torque-constant error (the hook cannot see the motor's current; gravity dominates these joints). mode
    "delay": r(t - d) - r(t): the reported torque lags the rigid torque by d [s]."""

    def __init__(self, j: int, mode: str, value: float):
        import pinocchio as pin

        from hardware.arms import load_arm

        self.pin, self.model = pin, load_arm("piper").pinocchio_model()
        self.data = self.model.createData()
        self.j, self.mode, self.value = j, mode, value
        self.hist_t: list[float] = []
        self.hist_r: list[float] = []

    def __call__(self, t, q, qd):
        q, qd = np.asarray(q, float), np.asarray(qd, float)
        r = float(self.pin.rnea(self.model, self.data, q, qd, np.zeros_like(qd))[self.j])
        tau = np.zeros(N_JOINTS)
        if self.mode == "scale":
            tau[self.j] = (self.value - 1.0) * r
            return tau
        if self.hist_t and t <= self.hist_t[-1]:  # the start-up test call, or a restart: no history
            self.hist_t, self.hist_r = [], []
        self.hist_t.append(t)
        self.hist_r.append(r)
        while len(self.hist_t) > 2 and self.hist_t[1] <= t - self.value:
            self.hist_t.pop(0)
            self.hist_r.pop(0)
        tau[self.j] = float(np.interp(t - self.value, self.hist_t, self.hist_r)) - r
        return tau


TWIN_CASES: dict[str, TwinCase] = {
    "none": TwinCase("none", None, lambda: None, "nothing injected"),
    "coulomb_friction": TwinCase("coulomb_friction", 1, _coulomb(1, 0.5), params={"fc": 0.5}),
    "viscous_friction": TwinCase("viscous_friction", 2, _viscous(2, 1.0), params={"fv": 1.0}),
    "stribeck_friction": TwinCase("stribeck_friction", 1, _stribeck(1, 0.6, 0.1),
                                  params={"fs": 0.6, "vs": 0.1}),
    "position_periodic": TwinCase("position_periodic", 2, _periodic(2, 0.3, 0.35, 0.4),
                                  params={"amp": 0.3, "period_rad": 0.35, "phase": 0.4}),
    "backlash": TwinCase("backlash", 0, _backlash(0, 0.4, 0.02), params={"amp": 0.4, "width_rad": 0.02}),
    "position_spring": TwinCase("position_spring", 3, _spring(3, 0.5, 0.2), params={"k": 0.5, "q0": 0.2}),
    "drift": TwinCase("drift", 1, _drift(1, 0.5 / 60), params={"rate_nm_per_s": 0.5 / 60}),
    "current_offset": TwinCase("current_offset", 4, _offset(4, 0.3), params={"offset": 0.3}),
    "delay": TwinCase("delay", 1, lambda: _RigidLoad(1, "delay", 0.1), params={"delay_s": 0.1}),
    "torque_constant_scale": TwinCase("torque_constant_scale", 2, lambda: _RigidLoad(2, "scale", 1.15),
                                      params={"scale": 1.15}),
    "coupling": TwinCase("coupling", 2, _coupling(2, 1, 1.0), params={"source_joint": 1, "fv": 1.0}),
    # an unknown payload is a change of the last link's inertial parameters: a nearly free rigid part (the
    # default 1e-3 pull toward the description) absorbs it, so this case uses the CLI's --prior-weight 1.0
    "payload": TwinCase("payload", N_JOINTS - 1, lambda: _payload_hook(),
                        note="0.3 kg 5 cm beyond the flange (hardware.sim.example_effects:piper_payload)",
                        params={"mass_kg": 0.3, "distance_m": 0.05}, prior_weight=1.0),
}


def _payload_hook():
    from hardware.sim.example_effects import piper_payload

    return piper_payload


def twin_rig(effects: dict[str, bool], description_error: bool = True):
    """sim-piper with only the follower (no leader to simulate) and the given actuator switches;
    description_error: the twin's arm is its true body, not the description (hardware/arms/true_body.py)."""
    from hardware.rigs import load_rig

    r = load_rig("sim-piper")
    tw = replace(r.twin, effects={**r.twin.effects, **effects}, description_error=description_error)
    return replace(r, leaders=[], cameras=[], pairs=[], twin=tw)


def record(seconds: float, seed: int, hook, effects: dict[str, bool], twin_seed: int = 0,
           rate_hz: float = 100.0, description_error: bool = True) -> dict[str, np.ndarray]:
    """One lockstep free-motion run of about `seconds` (coverage trajectory, seed `seed`) -> plain-log arrays.
    The twin's own temperature is not read by the driver, so no temperature array is logged."""
    from calibration.next.collect import ContactStop, collect_free_motion
    from calibration.trajectories import arm_coverage_trajectory
    from hardware.connect import open_rig

    traj = arm_coverage_trajectory("piper", minutes=seconds / 60.0, rate_hz=rate_hz, seed=seed)
    with open_rig(twin_rig(effects, description_error), clock="lockstep", effect=hook, seed=twin_seed) as s:
        try:
            run = collect_free_motion(s, "follower", traj, move_speed=0.5)
        except ContactStop as e:  # the coarse contact guard tripped: keep what was recorded, say so
            if e.run is None or len(e.run.t) < 100 * rate_hz / 10:
                raise
            run = e.run
    out = run.arrays()
    out["stopped"] = np.array(render(run.stopped))
    out["simulated"] = np.array(True)
    return out


def generate(folder, case: TwinCase, seconds: float = 60.0, heldout_seconds: float = 30.0,
             effects: dict[str, bool] | None = None, seed: int = 0, reuse: bool = False,
             description_error: bool = True) -> tuple[Path, Path]:
    """Write train.npz (trajectory seed `seed`) and heldout.npz (a different trajectory, seed+100) for
    `case` into `folder`; returns their paths. reuse: keep logs already there (lockstep runs are
    deterministic, so the same arguments give the same logs)."""
    from hardware.recording.plain_log import save_plain_log

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    eff = CLEAN_EFFECTS if effects is None else effects
    paths = []
    for name, secs, s in (("train", seconds, seed), ("heldout", heldout_seconds, seed + 100)):
        if reuse and (folder / f"{name}.npz").exists():
            paths.append(folder / f"{name}.npz")
            continue
        arrays = record(secs, s, case.make(), eff, twin_seed=s, description_error=description_error)
        p = folder / f"{name}.npz"
        save_plain_log(p, **arrays)
        paths.append(p)
    return paths[0], paths[1]


def piper_basis(prior_weight: float | None = None):
    """The rigid part for twin logs: pinocchio regressor of the Piper description (as `--arm piper`), pulled
    toward the description with `prior_weight` (default: PinocchioBasis's 1e-3; the CLI's is 1.0)."""
    from calibration.diagnosis.basis import PinocchioBasis
    from hardware.arms import load_arm

    model = load_arm("piper").pinocchio_model()
    return PinocchioBasis(model) if prior_weight is None else PinocchioBasis(model, ridge=prior_weight)


def diagnose_logs(train_paths, heldout_paths, declared=None, log=lambda s: None, prior_weight=None):
    """`factr2 diagnose TRAIN --heldout HELD --arm piper` as a function (plus `declared` first-pass effects;
    with no held-out paths the last quarter of the single training run is held out)."""
    from calibration.diagnosis.data import load_segments, split_heldout
    from calibration.diagnosis.loop import diagnose

    runs = [load_segments(p) for p in train_paths]  # per file, its contact-free stretches
    held = [seg for p in heldout_paths for seg in load_segments(p)] or None
    train, held = split_heldout(runs, held)
    return diagnose(piper_basis(prior_weight), train, held, log=log, declared=declared)


def twin_own(effect) -> bool:
    """Whether an effect found with no injection is one the shipped sim-piper twin really has on that joint
    (its actuator presets): friction always; Stribeck, backlash where configured; position_periodic at the
    configured ripple period (within 5 %); drift / torque-constant scale where heating changes K(T). Such a
    find is right, not spurious."""
    from hardware.sim.presets import arm_params

    p, j = arm_params("piper", n=None), effect.joint
    if j >= len(p.kt):
        return False
    fam = effect.family
    if fam in ("coulomb_friction", "viscous_friction"):
        return True
    if fam == "stribeck_friction":
        return bool(p.stribeck[j] > 0)
    if fam == "backlash":
        return bool(p.backlash[j] > 0)
    if fam == "position_periodic":
        period = 2 * np.pi / p.ripple_cycles[j]
        return bool(p.ripple_amp[j] > 0 and abs(effect.hyper["period_rad"] / period - 1) <= 0.05)
    if fam in ("drift", "torque_constant_scale"):
        return bool(p.kt_temp_coeff[j] != 0)
    return False


def first_pass(dg) -> list:
    """The effects a no-injection diagnosis found (the twin's own), as declared effects for the next runs."""
    from calibration.diagnosis.effects import Effect

    return [Effect(e.family, e.joint, dict(e.hyper), None, e.ref) for e in dg.model.effects]
