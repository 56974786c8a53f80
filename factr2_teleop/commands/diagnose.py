"""`factr2 diagnose`: fit a grey-box model to logs, trace its held-out residual to missing effects, add them.

    factr2 diagnose cal/data/free_motion.npz --out diag/                   # the arm the log names (or none)
    factr2 diagnose runs/*.npz --heldout other.npz --arm piper --out diag/  # pinocchio regressor of the arm
    factr2 diagnose runs/*.npz --arm none --out diag/                       # data-only basis in any case
    factr2 diagnose runs/*.npz --model next.ckpt --out diag/                # around a trained NEXT model

Logs written by this app name their arm (plain logs: `arm`, `arm_sha256`, `joint_names`; recordings: the
session metadata's `arms`), so no --arm is needed; --arm overrides, --arm none forces the data-only basis.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from hardware.errors import UserError

HELP = "find what a dynamics model misses: trace held-out residuals to friction, cogging, backlash, drift ..."


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="plain .npz logs (one run each) or .mcap recordings (one run per episode) to fit on")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--physics", action="store_true", help="grey-box physics model (the default)")
    src.add_argument("--model", metavar="CKPT", help="diagnose a trained NEXT checkpoint instead")
    p.add_argument("--arm", help="arm description (hardware.arms name or MJCF path): use its pinocchio "
                   "regressor as the rigid part (default: the arm the logs name); 'none' = data-only basis; "
                   "'pinocchio-sample' = pinocchio's sample manipulator")
    p.add_argument("--kt", help="torque constants N*m/A per joint, comma separated (current logs with --arm)")
    p.add_argument("--heldout", nargs="+", metavar="FILE", help="held-out runs (default: the last INPUT, or "
                   "the last quarter of a single INPUT)")
    p.add_argument("--out", required=True, help="output folder for report.json, report.md and plots")
    p.add_argument("--rel-gain", type=float, default=0.02, help="minimum relative held-out L1 gain (0.02)")
    p.add_argument("--abs-gain", type=float, default=0.005,
                   help="minimum absolute gain as a fraction of the joint's held-out RMS target (0.005)")
    p.add_argument("--prior-weight", type=float, default=1.0,
                   help="with --arm: ridge weight pulling base parameters toward the description's (1.0); "
                        "0.001 on a reference run (a calibration trajectory identifies the arm itself)")
    p.add_argument("--max-effects", type=int, default=20)
    p.add_argument("--declared", metavar="REPORT.json",
                   help="effects already known (a first pass: the `effects` of an earlier report.json); "
                        "fitted from the start, not counted as found. With --arm, the base parameters that "
                        "run identified become the prior: a payload is then the change since that run")
    p.add_argument("--no-plots", action="store_true")


def _arm(args, segs) -> tuple[str | None, str]:
    """(arm description to use or None, where that came from): --arm wins; else the one arm the logs name."""
    if args.arm:
        return (None, "--arm none") if args.arm == "none" else (args.arm, "--arm")
    named = sorted({s.arm for s in segs} - {""})
    if len(named) > 1:
        raise UserError(f"the logs name different arms ({', '.join(named)})", where=", ".join(args.inputs),
                        fix="diagnose the runs of one arm at a time, or pass --arm")
    return (named[0], "named by the logs") if named else (None, "")


def _kinematics(name: str | None, segs, n: int):
    """The pinocchio model of arm `name` (None: none), checked against the logs: joint count and names; a
    description that changed since the logs were written is used with a note."""
    if name is None:
        return None
    if name == "pinocchio-sample":
        import pinocchio as pin

        model = pin.buildSampleModelManipulator()
    else:
        try:
            from hardware.arms import load_arm
        except ImportError:
            raise UserError("arm descriptions are not installed", where="--arm",
                            fix="pass --arm none to use the data-only basis") from None
        from hardware.errors import ConfigError

        try:
            desc = load_arm(name)
        except ConfigError as e:
            raise UserError(f"cannot load arm description {name!r} ({e.what})", where="--arm",
                            fix="pass --arm NAME_OR_MJCF_PATH of the arm, or --arm none") from None
        logged = {s.joint_names for s in segs if s.arm == name and s.joint_names}
        if logged and logged != {tuple(desc.joint_names)}:
            raise UserError(f"the logs' joints {', '.join(sorted(logged)[0])} are not arm {name}'s "
                            f"{', '.join(desc.joint_names)}", where="--arm",
                            fix="pass the arm the logs come from")
        stale = {s.arm_sha256 for s in segs if s.arm == name and s.arm_sha256} - {desc.sha256}
        if stale:
            print(f"note: arm description {name} changed since the logs were written (sha256 "
                  f"{sorted(stale)[0][:12]} then, {desc.sha256[:12]} now); using the current one")
        model = desc.pinocchio_model()
    if model.nv != n:
        raise UserError(f"the arm has {model.nv} joints, the logs {n}", where="--arm",
                        fix="pick the arm the logs were recorded on")
    return model


def _basis(args, model, n: int, units: str):
    from calibration.diagnosis.basis import DataBasis, PinocchioBasis

    if model is None:
        return DataBasis(n)
    if units != "N*m":
        raise UserError("logs are in current [A]; the arm's regressor is in N*m", where="--arm",
                        fix="pass --kt K1,K2,... (N*m/A per joint), or --arm none for the data-only basis")
    return PinocchioBasis(model, ridge=args.prior_weight)


def _apply_kt(segments, kt: str | None, n: int):
    if not kt:
        return segments
    import numpy as np

    try:
        k = np.array([float(x) for x in kt.split(",")])
    except ValueError:
        raise UserError(f"cannot parse {kt!r}", where="--kt", fix="comma-separated numbers, N*m/A") from None
    if len(k) != n:
        raise UserError(f"{len(k)} torque constants for {n} joints", where="--kt", fix="one per joint")
    for s in segments:
        if s.units == "A":
            s.tau, s.units = s.tau * k, "N*m"
    return segments


def _declared(path: str, basis, n: int) -> list:
    """The `effects` of an earlier report.json as declared effects (their coefficients are refitted)."""
    import json

    from calibration.diagnosis.effects import Effect

    fix = "pass the report.json an earlier `factr2 diagnose` wrote"
    try:
        rep = json.loads(Path(path).read_text())
        items = rep["effects"]
        _reference(rep, basis, path)
        effects = [Effect.from_json(d, ref=basis.prior.copy()) for d in items]
    except OSError as e:
        raise UserError(f"cannot read it: {e.strerror}", where=path, fix=fix) from None
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise UserError(f"not a diagnosis report ({str(e)[:80]})", where=path, fix=fix) from None
    bad = [e for e in effects if e.joint >= n or e.hyper.get("other_joint", 0) >= n]
    if bad:
        raise UserError(f"{bad[0].family} on joint {bad[0].joint}: the logs have {n} joints", where=path,
                        fix="declare effects of the arm these logs come from")
    scaled = [e for e in effects if e.ref is not None]
    if scaled and hasattr(basis, "per_joint"):  # the data-only basis has no nominal rigid part to scale
        raise UserError(f"{scaled[0].family} needs an arm description (its feature is the rigid part)",
                        where=path, fix="add --arm, or remove that effect from the declared report")
    return effects


def _reference(rep: dict, basis, path: str) -> None:
    """The arm as an earlier run identified it (report.json `rigid_parameters`), as the prior of the rigid
    part (calibration.diagnosis.basis.reference_prior), when both runs use the same arm description."""
    rigid = rep.get("rigid_parameters")
    if rigid is None or not hasattr(basis, "cols"):
        return
    from calibration.diagnosis.basis import reference_prior

    try:
        reference_prior(basis, rigid["theta"], rigid["columns"])
    except ValueError as e:
        raise UserError(f"its base parameters are not this arm's ({str(e)[:120]})", where=path,
                        fix="declare a report of the same arm description, or pass --arm none") from None
    print(f"prior: the base parameters identified in {_short(path)} (not the description's)")


def _short(path: str) -> str:
    p = Path(path)
    return f"{p.parent.name}/{p.name}" if p.parent.name else p.name


def run(args) -> int:
    from calibration.diagnosis.data import load_segments, split_heldout
    from calibration.diagnosis.loop import LoopConfig, diagnose
    from calibration.diagnosis.report import write

    runs = [load_segments(p) for p in args.inputs]
    segs = [s for run in runs for s in run]
    held = [s for p in args.heldout for s in load_segments(p)] if args.heldout else None
    every = segs + (held or [])
    n = every[0].n
    if any(s.n != n for s in every) or len({s.units for s in every}) != 1:
        raise UserError("the logs differ in joint count or units", where=", ".join(args.inputs),
                        fix="diagnose runs of one arm at a time")
    _apply_kt(every, args.kt, n)
    train, heldout = split_heldout(runs, held)
    arm, arm_source = _arm(args, every)
    model = _kinematics(arm, every, n)
    cfg = LoopConfig(rel_gain=args.rel_gain, abs_gain=args.abs_gain, max_effects=args.max_effects)
    meta = {"units": every[0].units, "joint_names": list(every[0].joint_names) or None,
            "arm": arm, "arm_source": arm_source,
            "train_runs": [s.name for s in train], "heldout_runs": [s.name for s in heldout],
            "data_source": ", ".join(_short(p) for p in args.inputs) + (
                " | held out: " + ", ".join(_short(p) for p in args.heldout) if args.heldout else "")}
    t0 = time.perf_counter()
    if args.model:
        from calibration.diagnosis.next_loop import diagnose_next

        dg, extra = diagnose_next(args.model, train, heldout, cfg, log=print, kinematics=model,
                                  no_arm=args.arm == "none")
        meta.update(extra)
    else:
        basis = _basis(args, model, n, every[0].units)
        meta.update({"basis": basis.describe(), "title": "grey-box physics model"})
        declared = _declared(args.declared, basis, n) if args.declared else None
        dg = diagnose(basis, train, heldout, cfg, log=print, declared=declared)
    meta["seconds"] = round(time.perf_counter() - t0, 2)
    rep = write(dg, Path(args.out), meta, plots=not args.no_plots)
    print(rep["headline"])
    print(f"{rep['verdict']}")
    print(f"report: {Path(args.out) / 'report.md'}")
    return 0
