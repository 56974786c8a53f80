"""An unknown payload in kilograms from the real UR5's motor current (issue 57 item 2).

    FACTR2_SHARED=/work/shared python bench/bench_payload_ur5.py [--mass 1.5] [--com 0.01,-0.02,0.10]
                                                                 [--out bench/out/payload_ur5.json]

Data: the Kufieta 2014 UR5 logs (current [A], $FACTR2_SHARED/data/ur5_kufieta2014). The payload is ADDED to
the measured currents: i += s_true_j * Y_j(q, qd, qdd) @ (m, m c), Y the joint-torque regressor columns of
the last link's mass and first moment in the UR5 description (hardware/arms/ur5.urdf imported with
`factr2 arm import`, pinocchio), qd as logged, qdd the controller's commanded acceleration (`qdd_cmd`: not
the diagnosis' own differentiated one), s_true [A per N*m] the UR controller's own current_cmd / torque_cmd
ratio per joint (least squares over the runs) -- a scale the diagnosis is not told.

The base model is the calibration's own prior: the identified-current prior (calibration/next/
scaled_prior.py: the description corrected on the data, friction, ripple and a current-per-torque scale per
joint) fitted on the UNLOADED training runs. The loop (calibration/diagnosis, around a fixed model as with
`factr2 diagnose --model next.json --prior-only`) then diagnoses the LOADED runs -- training: the same five
runs with the payload, held out: three other trajectories with it -- with the payload's columns scaled as
each case allows:
  known       the true scale (as vendor torque constants would give it, `--kt`): mass in kg
  referenced  the prior's fitted scales, referenced to the description's masses: mass in kg
  known mass  the prior's scales times alpha from reference runs with a known 1.0 kg payload at another
              position (the five training trajectories run again with it, as a user would re-run the
              calibration trajectory with a known weight): mass in kg (`--known-mass`)
  unknown     the prior's scales with no reference for their common factor (`--mass-reference none`): the
              mass "cannot be stated in kg", the centre of mass can
Mass and centre of mass found against the truth with their 95 % moving-block bootstrap interval, the
payload's current (RMS over the held-out runs, per joint, A) found against the injected, and the held-out
L1 per joint: unloaded prior on the loaded runs -> after the loop. Writes JSON.
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

UR5 = Path(os.environ.get("FACTR2_SHARED", ROOT.parent / "shared")) / "data" / "ur5_kufieta2014"
TRAIN = ["Movement_No1", "Movement_No3_Acc", "Movement_No4_Acc", "Movement_No6_Acc_slow_Verify_Model",
         "Movement_No7_Acc_slow_Verify_Model_short"]
HELD = ["Movement_No2", "Movement_No5_Acc_slow_no_disturbance", "TEST"]
REFERENCE_KG, REFERENCE_COM = 1.0, (0.0, 0.0, 0.05)


def controller_scale(runs: list[dict]) -> np.ndarray:
    """[A per N*m] per joint: least-squares ratio of the UR controller's current_cmd to its torque_cmd."""
    i = np.concatenate([r["current_cmd"] for r in runs])
    tau = np.concatenate([r["torque_cmd"] for r in runs])
    return np.sum(i * tau, 0) / np.sum(tau * tau, 0)


def payload_current(model, run: dict, mass: float, com, scale: np.ndarray) -> np.ndarray:
    """(N, n) [A]: the payload's joint torques through the description's regressor, times scale."""
    from calibration.diagnosis.basis import payload_columns

    cols = payload_columns(model, run["q"], run["qd"], run["qdd_cmd"])
    return scale * (cols @ np.concatenate([[mass], mass * np.asarray(com, float)]))


def loaded(run: dict, extra: np.ndarray) -> dict:
    return {**run, "current": run["current"] + extra}


def save(folder: Path, name: str, run: dict) -> Path:
    path = folder / f"{name}.npz"
    np.savez(path, **run)
    return path


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--mass", type=float, default=1.5)
    ap.add_argument("--com", default="0.01,-0.02,0.10", help="m, in the last link's frame")
    ap.add_argument("--out", default=str(ROOT / "bench/out/payload_ur5.json"))
    ap.add_argument("--prior-cache", default="/tmp/factr2_payload_ur5_prior.json")
    args = ap.parse_args()
    if not UR5.exists():
        print(f"no UR5 logs at {UR5}")
        return 2
    com = [float(x) for x in args.com.split(",")]
    tmp = Path(tempfile.mkdtemp(prefix="payload_ur5_"))
    os.environ["FACTR2_ARMS"] = str(tmp / "arms")
    subprocess.run([sys.executable, "-m", "factr2_teleop.cli", "arm", "import",
                    str(ROOT / "hardware/arms/ur5.urdf"), "--name", "ur5", "--force", "--q-home",
                    "0,-1.57,1.57,-1.57,-1.57,0"], check=True, stdout=subprocess.DEVNULL,
                   env=dict(os.environ, PYTHONPATH=str(ROOT)))
    from calibration.diagnosis.data import load_segments
    from calibration.diagnosis.loop import diagnose
    from calibration.diagnosis.next_loop import _predictions, fixed_basis, known_mass_alpha
    from calibration.diagnosis.payload import CurrentScale, choose_scale
    from calibration.diagnosis.report import to_json
    from calibration.next.scaled_prior import ScaledPrior, fit_scaled_prior
    from hardware.arms import load_arm

    t0 = time.perf_counter()
    raw = {r: dict(np.load(UR5 / f"{r}.npz", allow_pickle=False)) for r in TRAIN + HELD}
    s_true = controller_scale(list(raw.values()))
    kin = load_arm("ur5").pinocchio_model()
    truth = {"mass_kg": args.mass, "com_m": com, "s_true_A_per_Nm": s_true.tolist()}
    inj = {r: payload_current(kin, a, args.mass, com, s_true) for r, a in raw.items()}
    folder = tmp / "logs"
    folder.mkdir()
    paths = {r: save(folder, r, loaded(a, inj[r])) for r, a in raw.items()}
    ref_paths = [save(folder, f"reference_{r}",
                      loaded(raw[r], payload_current(kin, raw[r], REFERENCE_KG, REFERENCE_COM, s_true)))
                 for r in TRAIN]
    # the calibration's own prior, on the unloaded training runs (kept between runs: 3 min to fit)
    cache = Path(args.prior_cache)
    if cache.exists() and json.loads(cache.read_text()).get("train") == TRAIN:
        prior = ScaledPrior.from_dict(json.loads(cache.read_text())["prior"])
    else:
        prior = fit_scaled_prior("ur5", [(a["t"], a["q"], a["qd"], a["current"]) for r, a in raw.items()
                                         if r in TRAIN])
        cache.write_text(json.dumps({"train": TRAIN, "prior": prior.to_dict()}))
    print(f"prior fitted in {time.perf_counter() - t0:.0f} s; scales {np.round(prior.scale, 4).tolist()}, "
          f"controller's {np.round(s_true, 4).tolist()}", flush=True)

    def predict(segs):
        return _predictions(None, None, 1, "", 100.0, segs, prior)

    # the floor: the prior on the held-out runs WITHOUT the payload (what a perfect payload model reaches)
    from calibration.diagnosis.greybox import errors

    segs_u, preds_u = predict([s for r in HELD for s in load_segments(UR5 / f"{r}.npz")])
    floor = errors(np.concatenate([s.tau for s in segs_u]),
                   np.concatenate([preds_u[id(s)] for s in segs_u]))[0].tolist()
    print(f"held-out L1 of the prior without payload (floor): {np.round(floor, 3).tolist()}", flush=True)
    train = [s for r in TRAIN for s in load_segments(paths[r])]
    held = [s for r in HELD for s in load_segments(paths[r])]
    ref_segs = [s for p in ref_paths for s in load_segments(p)]
    names = list(load_arm("ur5").joint_names)
    out = {"truth": truth, "prior_scale_A_per_Nm": prior.scale.tolist(), "train": TRAIN, "heldout": HELD,
           "reference_runs": {"runs": TRAIN, "mass_kg": REFERENCE_KG, "com_m": list(REFERENCE_COM)},
           "joints": names, "heldout_l1_unloaded_floor": floor, "cases": {}}
    cases = {"known": CurrentScale(s_true, "torque constants", "the controller's current_cmd / torque_cmd"),
             "referenced": choose_scale("A", prior_scale=prior.scale),
             "known mass": None, "unknown": choose_scale("A", prior_scale=prior.scale, referenced=False)}
    for case, scale in cases.items():
        basis, tr, ho = fixed_basis(train, held, predict, "identified-current prior (unloaded runs)", kin,
                                    scale or cases["referenced"])
        if scale is None:
            alpha = known_mass_alpha(basis, ref_segs, predict, REFERENCE_KG)
            scale = choose_scale("A", prior_scale=prior.scale, known_alpha=alpha)
            basis.current_scale = scale.scale
        dg = diagnose(basis, tr, ho)
        rep = to_json(dg, {"units": "A", "joint_names": names, "payload_scale": scale,
                           "prior_only": True})
        k = next((i for i, e in enumerate(dg.model.effects) if e.family == "payload"), None)
        row = {"first": dg.steps[1].added["effect"] if len(dg.steps) > 1 else None,
               "found": [(e.family, e.joint) for e in dg.model.effects], "headline": rep["headline"],
               "heldout_l1_before": dg.steps[0].heldout_l1, "heldout_l1_after": rep["after"]["heldout_l1"],
               "scale_used": scale.to_json(), "payload": rep.get("payload")}
        if k is not None:
            e = dg.model.effects[k]
            feats = dg.heldout.features(e)
            found_i = np.einsum("tjk,k->tj", feats, e.coef)
            true_i = np.concatenate([inj[r] for r in HELD])  # not cut like the design: RMS compared only
            row["payload_current_rms_found_A"] = np.sqrt(np.mean(found_i ** 2, 0)).tolist()
            row["payload_current_rms_true_A"] = np.sqrt(np.mean(true_i ** 2, 0)).tolist()
            p = rep["payload"]
            row["mass_err"] = (p["mass"] / args.mass - 1) if p["mass_kg"] is not None else None
            row["com_err_m"] = float(np.linalg.norm(np.array(p["com_m"]) - np.array(com)))
        out["cases"][case] = row
        l1b, l1a = (np.round(row[x], 3).tolist() for x in ("heldout_l1_before", "heldout_l1_after"))
        print(f"{case}: first {row['first']}; {(row['payload'] or {}).get('words')}; held-out L1 {l1b} -> "
              f"{l1a}", flush=True)
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
