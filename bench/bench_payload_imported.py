"""Diagnosis in physical units on the twin of an IMPORTED arm (issue 34 item 5). SIMULATED.

    python -m bench.bench_payload_imported [--mass 2.0] [--com 0,0,0.1] [--train-s 60] [--heldout-s 30]
                                           [--seed 0]

1. `factr2 arm import hardware/arms/ur5.urdf --name ur5` into a temporary $FACTR2_ARMS (not a built-in arm).
2. Its twin (MuJoCo from the same URDF, the default actuator effects of an imported arm: hardware/sim/presets
   "generic"; mechanical effects off as in calibration/diagnosis/twin_data.py unless --mechanical, sensor
   effects on) replays coverage trajectories in lockstep: a calibration run without payload, then train /
   held-out runs with an undeclared payload (MASS kg at COM m in the last link's frame) that goes in only
   through the twin's undeclared-effect hook (its gravity torque inside the drive).
3. Diagnosis with the imported description (calibration.diagnosis, PinocchioBasis of the imported arm): a
   reference pass on the no-payload runs identifies the arm itself (weak prior REFERENCE_RIDGE), then the
   payload runs are diagnosed with its effects declared and its base parameters as the prior
   (basis.reference_prior: a payload's columns lie in the base regressor's span, so it is only the change
   against such a reference). The first effect found, its mass [kg] and position [m].
4. The same logs in motor current, i = s * tau with s [A per N*m] per joint (UR5-like 0.12 / 0.08 / 0.5):
   (a) known torque constant: i / s_known back to N*m; (b) no torque constant: s identified on the
   no-payload calibration run by the current-scaled prior (calibration/next/scaled_prior.py), which the CAD
   masses anchor (the "one known mass" of docs/arms_import.md), then i / s_fitted. Each diagnosed as in 3.

   (c) in current, around the calibration's own prior (issue 57): the identified-current prior fitted on the
   no-payload calibration run IN CURRENT is the base model (as `factr2 diagnose --model next.json
   --prior-only`), and the payload's regressor columns are scaled by that prior's per-joint scales (CAD-
   referenced: calibration/diagnosis/payload.py); the loop ranks it against gravity_load per joint. The
   report's mass (with its bootstrap interval) and centre of mass.

Writes bench/out/payload_imported.json and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

S_CURRENT = np.array([0.12, 0.08, 0.12, 0.5, 0.5, 0.5])  # A per N*m: the "drive" of the current logs
CLEAN = {k: False for k in ("friction", "stribeck", "backlash", "ripple", "thermal", "kt_temperature")}


def _rig(folder: Path, body_seed: int, mechanical: bool = False):
    """The imported arm's twin, follower only, mechanical effects off unless `mechanical` (sensor effects
    on); its true body (hardware/arms/true_body.py: +-15 % mass, +-1 cm centre of mass per link) drawn from
    body_seed."""
    from hardware.rigs import load_rig

    path = folder / "sim-ur5-imported.toml"
    path.write_text('[rig]\nname = "sim-ur5-imported"\ndescription = "imported UR5 twin"\nsimulated = true\n'
                    '[[followers]]\nname = "follower"\ndriver = "sim"\narm = "ur5"\n'
                    f'[twin]\nseed = {body_seed}\nscene = "table"\n[twin.effects]\n'
                    + ("" if mechanical else "".join(f"{k} = false\n" for k in CLEAN)))
    return load_rig(path)


def _payload_hook(mass: float, com):
    import pinocchio as pin

    from hardware.arms import load_arm
    from hardware.sim.example_effects import with_payload

    m = load_arm("ur5").pinocchio_model()
    ml = with_payload(m, mass, com, 1e-4)
    d, dl = m.createData(), ml.createData()

    def hook(t, q, qd):
        q = np.asarray(q, float)
        return pin.computeGeneralizedGravity(ml, dl, q) - pin.computeGeneralizedGravity(m, d, q)
    return hook


def record(folder: Path, seconds: float, seed: int, hook, body_seed: int = 0,
           mechanical: bool = False) -> dict:
    from calibration.next.collect import ContactStop, collect_free_motion
    from calibration.trajectories import arm_coverage_trajectory
    from hardware.connect import open_rig

    traj = arm_coverage_trajectory("ur5", minutes=seconds / 60.0, rate_hz=100.0, seed=seed)
    with open_rig(_rig(folder, body_seed, mechanical), clock="lockstep", effect=hook, seed=seed) as s:
        try:
            run = collect_free_motion(s, "follower", traj, move_speed=0.5)
        except ContactStop as e:
            run = e.run
    return run.arrays()


def _save(folder: Path, name: str, arrays: dict, tau_scale=None) -> Path:
    from hardware.recording.plain_log import save_plain_log

    a = dict(arrays)
    if tau_scale is not None:  # a log in current: tau_m replaced by i = s * tau, no N*m signal in the file
        a["current"] = a.pop("tau_m") * tau_scale
    path = folder / f"{name}.npz"
    save_plain_log(path, **a)
    return path


def diagnose(train: Path, held: Path, reference=None):
    """Diagnose train/held with the imported arm's regressor. reference: None for the reference pass itself
    (weak prior: the arm identified on its own, REFERENCE_RIDGE), else that pass' Diagnosis: its effects
    declared and its base parameters the prior (basis.reference_prior), so a payload is the change since."""
    from calibration.diagnosis.basis import REFERENCE_RIDGE, PinocchioBasis, reference_prior
    from calibration.diagnosis.data import load_segments, split_heldout
    from calibration.diagnosis.loop import diagnose as run
    from calibration.diagnosis.twin_data import first_pass
    from hardware.arms import load_arm

    tr, he = split_heldout([load_segments(train)], list(load_segments(held)))
    if reference is None:
        return run(PinocchioBasis(load_arm("ur5").pinocchio_model(), ridge=REFERENCE_RIDGE), tr, he)
    basis = PinocchioBasis(load_arm("ur5").pinocchio_model(), ridge=1.0)
    reference_prior(basis, reference.model.theta, reference.model.basis.cols)
    return run(basis, tr, he, declared=first_pass(reference))


def in_current(prior, calib, plain_held, train, held, mass: float, com) -> dict:
    """Case (c): the loaded runs in current, diagnosed around the identified-current prior fitted on the
    unloaded calibration run, the payload's columns times its scales (payload.choose_scale)."""
    import tempfile as tf

    from calibration.diagnosis.data import load_segments
    from calibration.diagnosis.loop import diagnose as run
    from calibration.diagnosis.next_loop import _predictions, fixed_basis
    from calibration.diagnosis.payload import choose_scale
    from calibration.diagnosis.report import to_json
    from hardware.arms import load_arm

    folder = Path(tf.mkdtemp(prefix="payload_current_"))
    paths = {k: _save(folder, k, a, S_CURRENT) for k, a in (("train", train), ("held", held))}
    scale = choose_scale("A", prior_scale=prior.scale)

    def predict(segs):
        return _predictions(None, None, 1, "", 100.0, segs, prior)

    basis, tr, ho = fixed_basis(load_segments(paths["train"]), load_segments(paths["held"]), predict,
                                "identified-current prior", load_arm("ur5").pinocchio_model(), scale)
    dg = run(basis, tr, ho)
    rep = to_json(dg, {"units": "A", "payload_scale": scale, "prior_only": True})
    r = first_payload(dg)
    p = rep.get("payload")
    if p:
        r["mass_err"] = p["mass"] / mass - 1
        r["position_err_m"] = float(np.linalg.norm(np.array(p["com_m"]) - np.array(com)))
        r["interval"] = p.get("interval")
        r["words"] = p["words"]
    r["headline"] = rep["headline"]
    r["heldout_l1_before"], r["heldout_l1_after"] = dg.steps[0].heldout_l1, rep["after"]["heldout_l1"]
    print(f"A, in current around the prior: first {r['first']}; {r.get('words')}; mass err "
          f"{r.get('mass_err', np.nan):+.1%}", flush=True)
    return r


def first_payload(dg) -> dict:
    added = [s.added for s in dg.steps[1:] if s.added]
    first = added[0] if added else None
    pay = next((e for e in dg.model.effects if e.family == "payload"), None)
    return {"first": None if first is None else first.get("effect"),
            "added": [a.get("effect") for a in added],
            "payload": None if pay is None else pay.params()}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--mass", type=float, default=2.0)
    ap.add_argument("--com", default="0,0,0.1")
    ap.add_argument("--train-s", type=float, default=60.0)
    ap.add_argument("--heldout-s", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=0, help="trajectory and twin seed of the first run")
    ap.add_argument("--mechanical", action="store_true",
                    help="the twin's mechanical effects on too (friction, Stribeck, backlash, ripple, "
                         "thermal)")
    ap.add_argument("--only-current", action="store_true", help="case (c) only")
    ap.add_argument("--out", default=str(ROOT / "bench/out/payload_imported.json"))
    args = ap.parse_args()
    com = [float(v) for v in args.com.split(",")]
    tmp = Path(tempfile.mkdtemp(prefix="payload_imported_"))
    os.environ["FACTR2_ARMS"] = str(tmp / "arms")
    subprocess.run([sys.executable, "-m", "factr2_teleop.cli", "arm", "import",
                    str(ROOT / "hardware/arms/ur5.urdf"), "--name", "ur5", "--q-home",
                    "0,-1.57,1.57,-1.57,-1.57,0", "--armature", "0.1,0.1,0.1,0.02,0.02,0.02"], check=True,
                   stdout=subprocess.DEVNULL, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    t0 = time.perf_counter()
    s = args.seed
    mech = args.mechanical
    calib = record(tmp, args.train_s, s, None, s, mech)
    plain_held = record(tmp, args.heldout_s, s + 100, None, s, mech)
    hook = _payload_hook(args.mass, com)
    train = record(tmp, args.train_s, s + 1, hook, s, mech)
    held = record(tmp, args.heldout_s, s + 101, hook, s, mech)
    # the coverage recipe always sweeps every joint alone first (79 s on the UR5), so a run is never shorter
    lengths = [float(r["t"][-1] - r["t"][0]) for r in (calib, plain_held, train, held)]
    print(f"twin runs recorded in {time.perf_counter() - t0:.0f} s (one unit: true body seed {s}; trajectory "
          f"and noise seeds {s}, {s + 100} without payload, {s + 1}, {s + 101} with it; "
          f"{', '.join(f'{x:.0f}' for x in lengths)} s long)", flush=True)
    truth = {"mass_kg": args.mass, "com_m": com}
    out = {"truth": truth, "seed": s, "mechanical_effects": mech, "run_lengths_s": lengths, "cases": {}}
    from calibration.next.scaled_prior import fit_scaled_prior

    c = calib
    fitted_prior = fit_scaled_prior("ur5", [(c["t"], c["q"], c["qd"], c["tau_m"] * S_CURRENT)])
    fitted = fitted_prior.scale
    print("current-per-torque scale fitted on the no-payload run [A per N*m]:", np.round(fitted, 4).tolist())
    for case, scale_in, scale_back in (("N*m", None, None),
                                       ("A, known torque constant", S_CURRENT, S_CURRENT),
                                       ("A, scale identified (CAD masses)", S_CURRENT, fitted)
                                       )[3 if args.only_current else 0:]:
        runs = {"calib": calib, "calib_held": plain_held, "train": train, "held": held}
        if scale_in is not None:  # through current and back with the scale the case knows
            runs = {k: {**a, "tau_m": a["tau_m"] * scale_in / scale_back} for k, a in runs.items()}
        paths = {k: _save(tmp, k, a) for k, a in runs.items()}
        ref = diagnose(paths["calib"], paths["calib_held"])  # the arm without payload, in this case's units
        dg = diagnose(paths["train"], paths["held"], reference=ref)
        r = first_payload(dg)
        p = r["payload"] or {}
        if p:
            found = np.array([p["com_x_m"], p["com_y_m"], p["com_z_m"]])
            r["mass_err"] = p["mass_kg"] / args.mass - 1
            r["position_err_m"] = float(np.linalg.norm(found - np.array(com)))
            r["position_err_rel"] = r["position_err_m"] / float(np.linalg.norm(com))
        r["reference_effects"] = [(e.family, e.joint) for e in ref.model.effects]
        out["cases"][case] = r
        xyz = ", ".join(f"{p.get(k, np.nan):.3f}" for k in ("com_x_m", "com_y_m", "com_z_m"))
        print(f"{case:36s} first {r['first']}; payload {p.get('mass_kg', np.nan):.3f} kg at ({xyz}) m; "
              f"mass err {r.get('mass_err', np.nan):+.1%}, "
              f"position err {r.get('position_err_m', np.nan):.3f} m",
              flush=True)
    out["cases"]["A, in current around the prior (scaled columns)"] = in_current(
        fitted_prior, calib, plain_held, train, held, args.mass, com)
    out["scale_fitted"] = fitted.tolist()
    out["scale_true"] = S_CURRENT.tolist()
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
