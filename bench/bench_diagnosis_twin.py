"""Close the diagnosis loop on twin data: inject each effect family through the twin's undeclared-effect
hook, diagnose, and check family / joint / parameters and the held-out error on that joint. SIMULATED.

    python -m bench.bench_diagnosis_twin                       # full table -> docs/diagnosis_twin.md
    python -m bench.bench_diagnosis_twin --train-s 30 --heldout-s 30 --cases position_periodic --no-defaults

Protocol (calibration/diagnosis/twin_data.py): sim-piper in lockstep through the real Piper driver, coverage
trajectories (train: seed 0, held out: a different trajectory, seed 100). Rigid part: the pinocchio regressor
of the Piper description (as `factr2 diagnose --arm piper`).
1. First pass: no injection, same trajectories -> the effects the twin itself shows (declared afterwards).
2. Each family: same trajectories + the hook; diagnose with the first pass declared. Pass = the first effect
   added is the injected family on the injected joint (position_periodic: period within 5 %), and that
   joint's held-out L1 after the loop is <= 50 % of before (before = rigid part + declared effects).
   payload (hardware.sim.example_effects:piper_payload, 0.3 kg 5 cm beyond the flange, a static load): first
   found, mass within 20 %, held-out L1 summed over the joints it loads (>= 20 % of the largest joint's
   payload torque) <= 50 % of before.
3. No injection, fresh trajectories (seeds 1 / 101): pass = nothing added ("the model explains the data").
Set A: the twin's mechanical effects off (sensor noise / quantisation / current limit on). Set B (unless
--no-defaults): the shipped twin, all effects on (friction, Stribeck, backlash, ripple, heating, K(T)).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from calibration.diagnosis.greybox import errors
from calibration.diagnosis.twin_data import (
    CLEAN_EFFECTS,
    TWIN_CASES,
    TWIN_DEFAULTS,
    diagnose_logs,
    first_pass,
    generate,
    twin_own,
)


def judge(case, dg, own_ok: bool = False) -> dict:
    """One table row: what the loop added first, its parameters and the injected joint's held-out L1.
    own_ok (the shipped twin, set B): with nothing injected, an effect the twin really has is not spurious."""
    steps = [s.added for s in dg.steps[1:]]
    found = [(e.family, e.joint) for e in dg.found()]
    row = {"found": found, "first": (steps[0]["effect"], steps[0]["joint"]) if steps else None}
    if case.family == "none":
        spurious = [(e.family, e.joint) for e in dg.found() if not (own_ok and twin_own(e))]
        row["ok"] = not spurious
        own = [f"{e.family} j{e.joint} {_fmt_params(e.params())}" for e in dg.found()
               if own_ok and twin_own(e)]
        row["note"] = ("explains the data" if not found else
                       (f"spurious: {spurious}; " if spurious else "") +
                       (f"found the twin's own {'; '.join(own)}" if own else ""))
        return row
    j = case.joint
    l1_after, _ = errors(dg.heldout.y, dg.model.predict(dg.heldout))
    row["before"], row["after"] = dg.steps[0].heldout_l1[j], float(l1_after[j])
    if case.family == "payload":  # it acts on every joint: judged on the joints it loads
        aff = affected_joints(dg.heldout.q)
        row["before"] = float(np.sum(np.asarray(dg.steps[0].heldout_l1)[aff]))
        row["after"] = float(np.sum(l1_after[aff]))
        row["note"] = f"L1 summed over joints {', '.join(map(str, aff))}"
    hit = next((e for e in dg.model.effects if (e.family, e.joint) == (case.family, j)), None)
    row["params"] = hit.params() if hit is not None else {}
    ok = row["first"] == (case.family, j) and hit is not None and row["after"] <= 0.5 * row["before"]
    if case.family == "position_periodic" and hit is not None:
        err = abs(hit.hyper["period_rad"] / case.params["period_rad"] - 1)
        row["period_err"] = err
        ok = ok and err <= 0.05
    if case.family == "payload" and hit is not None:
        err = abs(hit.params()["mass_kg"] / case.params["mass_kg"] - 1)
        row["mass_err"] = err
        ok = ok and err <= 0.2
    row["ok"] = ok
    row.setdefault("note", "")
    return row


def affected_joints(q: np.ndarray, share: float = 0.2) -> list[int]:
    """Joints whose injected payload torque (RMS over the held-out motion) is at least `share` of the
    largest joint's."""
    from hardware.sim.example_effects import piper_payload

    rms = np.sqrt(np.mean(np.stack([piper_payload(0.0, x, x * 0) for x in q[::10]]) ** 2, 0))
    return [int(k) for k in np.flatnonzero(rms >= share * rms.max())]


def _fmt_params(p: dict) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in p.items() if isinstance(v, (int, float)))


def run_set(label, effects, cases, data, train_s, held_s, log, description_error=True):
    rows = []
    folder = data / label.split(":")[0]
    base = generate(folder / "first_pass", TWIN_CASES["none"], train_s, held_s, effects, seed=0,
                    reuse=True, description_error=description_error)
    dg0 = diagnose_logs([base[0]], [base[1]])
    declared = first_pass(dg0)
    log(f"[{label}] first pass: {[(e.family, e.joint) for e in declared]}")
    for name in cases:
        case = TWIN_CASES[name]
        t0 = time.perf_counter()
        seed = 1 if name == "none" else 0
        row = {"set": label, "case": name, "family": case.family, "joint": case.joint,
               "injected": _fmt_params(case.params)}
        try:
            tr, he = generate(folder / name, case, train_s, held_s, effects, seed=seed, reuse=True,
                              description_error=description_error)
        except Exception as e:  # noqa: BLE001 - a failed recording is a FAIL row, not a lost table
            rows.append({**row, "found": [], "first": None, "ok": False, "before": np.nan, "after": np.nan,
                         "params": {}, "note": f"recording failed: {str(e).splitlines()[0][:120]}"})
            log(f"[{label}] {name}: {rows[-1]['note']}")
            continue
        stopped = str(np.load(tr)["stopped"]) if "stopped" in np.load(tr).files else ""
        dg = diagnose_logs([tr], [he], declared=declared, prior_weight=case.prior_weight)
        row.update({**judge(case, dg, own_ok=effects is TWIN_DEFAULTS), "seconds": time.perf_counter() - t0})
        if stopped:
            why = f"train run stopped early ({stopped} guard)"
            row["note"] = "; ".join(x for x in (row.get("note"), why) if x)
        log(f"[{label}] {name}: {row}")
        rows.append(row)
    return declared, rows


def table(sets, args, wall) -> str:
    out = ["# Diagnosis on twin data (SIMULATED)", "",
           "Generated by `python -m bench.bench_diagnosis_twin " + " ".join(sys.argv[1:]) + "` on "
           f"{platform.node()} ({platform.machine()}, {platform.system()}; {os.cpu_count()} CPU cores, load "
           f"average {os.getloadavg()[0]:.1f} at the end) in {wall:.0f} s. Data: sim-piper twin in lockstep "
           "through the Piper driver, "
           + ("simulating the description exactly (--exact-description)" if args.exact_description else
              "its arm a true body that differs from the description (hardware/arms/true_body.py, drawn "
              "from the rig file's twin seed: one unit for every run)") + "; train "
           f"{args.train_s:.0f} s coverage trajectory (seed 0), held out a different {args.heldout_s:.0f} s "
           "trajectory (seed 100); the no-injection check uses fresh trajectories (seeds 1 / 101). "
           "Rigid part: pinocchio regressor of the Piper description (`--arm piper` basis; pulled toward the "
           "description with weight 1e-3, the payload rows with the CLI's default --prior-weight 1.0: a "
           "nearly free rigid part absorbs a payload, which is a change of the last link's mass). Effects "
           "injected "
           "only through the twin's undeclared-effect hook. Protocol: bench/bench_diagnosis_twin.py "
           "docstring; joints 0-based; L1 in N*m. Logs already under --data are reused (lockstep runs are "
           "deterministic), so the time above may cover the diagnoses only.", ""]
    for label, declared, rows in sets:
        out += [f"## {label}", "", "First pass (no injection, declared in every row below): "
                + (", ".join(f"{e.family} j{e.joint}" for e in declared) or "nothing"), "",
                "| injected family | joint | injected | first found | all found | params found | "
                "held-out L1 joint before -> after | pass |", "|---|---|---|---|---|---|---|---|"]
        for r in rows:
            first = f"{r['first'][0]} j{r['first'][1]}" if r["first"] else "-"
            found = ", ".join(f"{f} j{j}" for f, j in r["found"]) or "-"
            if r["family"] == "none" or not np.isfinite(r.get("before", 0.0)):
                l1 = r["note"]
                params = "-"
            else:
                l1 = f"{r['before']:.4f} -> {r['after']:.4f} ({100 * r['after'] / r['before']:.0f} %)"
                params = _fmt_params(r["params"]) or "-"
                if "period_err" in r:
                    params += f" (period error {100 * r['period_err']:.1f} %)"
                if "mass_err" in r:
                    params += f" (mass error {100 * r['mass_err']:.1f} %)"
                if r.get("note"):
                    l1 += f"; {r['note'].strip()}"
            joint = "-" if r["joint"] is None else r["joint"]
            out.append(f"| {r['family']} | {joint} | {r['injected'] or '-'} "
                       f"| {first} | {found} | {params} | {l1} | {'PASS' if r['ok'] else 'FAIL'} |")
        out.append("")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--train-s", type=float, default=60.0)
    p.add_argument("--heldout-s", type=float, default=30.0)
    p.add_argument("--cases", nargs="+", default=[c for c in TWIN_CASES if c != "none"] + ["none"])
    p.add_argument("--no-defaults", action="store_true", help="skip set B (the twin with all effects on)")
    p.add_argument("--data", default="/tmp/factr2_diag_twin", help="where the generated logs go")
    p.add_argument("--exact-description", action="store_true",
                   help="the twin simulates the Piper description exactly (rig description_error = false)")
    p.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "diagnosis_twin.md"))
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    data = Path(args.data)
    sets = []
    err = not args.exact_description
    d, rows = run_set("A: twin mechanical effects off", CLEAN_EFFECTS, args.cases, data, args.train_s,
                      args.heldout_s, print, err)
    sets.append(("A: twin mechanical effects off (noise, quantisation, current limit on)", d, rows))
    if not args.no_defaults:
        d, rows = run_set("B: twin defaults on", TWIN_DEFAULTS, ["position_periodic", "payload", "none"],
                          data, args.train_s, args.heldout_s, print, err)
        sets.append(("B: the shipped twin, all effects on (friction, Stribeck, backlash, ripple, heating, "
                     "K(T))", d, rows))
    text = table(sets, args, time.perf_counter() - t0)
    Path(args.out).write_text(text + "\n")
    print(text)
    for label, _, rs in sets:
        print(f"{label.split(':')[0]}: {sum(r['ok'] for r in rs)}/{len(rs)} pass")
    print(f"table: {args.out}")
    # set A is the protocol (one undeclared effect on the nominal arm); set B is a realism check, reported
    return 0 if all(r["ok"] for r in sets[0][2]) else 1


if __name__ == "__main__":
    raise SystemExit(main())
