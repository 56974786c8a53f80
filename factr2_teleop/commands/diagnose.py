"""`factr2 diagnose`: fit a grey-box model to logs, trace its held-out residual to missing effects, add them.

    factr2 diagnose cal/data/free_motion.npz --out diag/                   # the arm the log names (or none)
    factr2 diagnose runs/*.npz --heldout other.npz --arm piper --out diag/  # pinocchio regressor of the arm
    factr2 diagnose runs/*.npz --arm none --out diag/                       # data-only basis in any case
    factr2 diagnose runs/*.npz --model next.ckpt --out diag/                # around a trained NEXT model
    factr2 diagnose loaded/*.npz --model next.json --prior-only --out diag/ # around its physics prior alone

A payload in current goes through the arm's kinematics with the checkpoint's identified-current scales
(the description's masses as reference), --kt, or --known-mass KG --known-mass-run RUN; the report says
which (calibration/diagnosis/payload.py). Joint names: calibration/joint_map.py (--joint-map).

Logs written by this app name their arm (plain logs: `arm`, `arm_sha256`, `joint_names`; recordings: the
recording metadata's `arms`), so no --arm is needed; --arm overrides, --arm none forces the data-only basis.
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
    p.add_argument("--prior-only", action="store_true",
                   help="with --model: the checkpoint's physics prior alone is the base model (the "
                        "calibration's own prior, without the network)")
    p.add_argument("--known-mass", type=float, metavar="KG",
                   help="with --model on current logs: the mass of a payload on --known-mass-run, which "
                        "sets the common current-per-torque factor (the payload's mass is then in kg)")
    p.add_argument("--known-mass-run", nargs="+", metavar="FILE",
                   help="the run(s) with the --known-mass payload")
    p.add_argument("--mass-reference", choices=("description", "none"), default="description",
                   help="with --model on current logs: whether the identified-current prior's scales count "
                        "as referenced to the description's masses (kg) or not ('none': the mass cannot be "
                        "stated in kg, the centre of mass still is)")
    p.add_argument("--joint-map", metavar="LOG=ARM,...",
                   help="which arm joint each log joint is (every log joint once), when the names differ by "
                        "more than a common prefix/suffix or come in another order")
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
        stale = {s.arm_sha256 for s in segs if s.arm == name and s.arm_sha256} - {desc.sha256}
        if stale:
            print(f"note: arm description {name} changed since the logs were written (sha256 "
                  f"{sorted(stale)[0][:12]} then, {desc.sha256[:12]} now); using the current one")
        model = desc.pinocchio_model()
    if model.nv != n:
        raise UserError(f"the arm has {model.nv} joints, the logs {n}", where="--arm",
                        fix="pick the arm the logs were recorded on")
    return model


def _joint_order(args, arm: str | None, segs, n: int):
    """(order, arm joint names) matching the logs' columns to the arm's joints (calibration.joint_map),
    None when there is no described arm; the one line it has to say is printed."""
    if arm is None or arm == "pinocchio-sample":
        return None
    from calibration.joint_map import JointMismatch, match_joints
    from hardware.arms import load_arm
    from hardware.errors import ConfigError

    try:
        want = list(load_arm(arm).joint_names)
    except ConfigError as e:
        raise UserError(f"cannot load arm description {arm!r} ({e.what})", where="--arm",
                        fix="pass --arm NAME_OR_MJCF_PATH of the arm, or --arm none") from None
    named = sorted({s.joint_names for s in segs if s.joint_names})
    if len(named) > 1:
        raise UserError(f"the logs name different joints ({'; '.join(', '.join(x) for x in named)})",
                        where=", ".join(args.inputs), fix="diagnose the runs of one arm at a time")
    try:
        order, note = match_joints(named[0] if named else (), want, args.joint_map, arm, n)
    except JointMismatch as e:
        raise UserError(e.what, where="--joint-map" if args.joint_map else "joint names", fix=e.fix) from None
    except ValueError as e:
        raise UserError(str(e), where="--joint-map",
                        fix="LOG_NAME=ARM_NAME,... for every log joint") from None
    if note:
        print(f"note: {note}")
    return order, want


def _basis(args, model, n: int, units: str):
    from calibration.diagnosis.basis import DataBasis, PinocchioBasis

    if model is None:
        return DataBasis(n)
    if units != "N*m":
        raise UserError("logs are in current [A]; the arm's regressor is in N*m", where="--arm",
                        fix="pass --kt K1,K2,... (N*m/A per joint), or --model next.json --prior-only of a "
                            "calibration on these logs (its prior's current scales), or --arm none")
    return PinocchioBasis(model, ridge=args.prior_weight)


def _parse_kt(kt: str | None, n: int):
    """--kt as (n,) N*m per A (arm joint order), or None."""
    if not kt:
        return None
    import numpy as np

    try:
        k = np.array([float(x) for x in kt.split(",")])
    except ValueError:
        raise UserError(f"cannot parse {kt!r}", where="--kt", fix="comma-separated numbers, N*m/A") from None
    if len(k) != n:
        raise UserError(f"{len(k)} torque constants for {n} joints", where="--kt", fix="one per joint")
    if not np.all(np.isfinite(k)) or np.any(k == 0):
        raise UserError(f"torque constants {kt} must be finite and non-zero", where="--kt",
                        fix="the vendor's N*m per A of each joint (with the gear ratio)")
    return k


def _apply_kt(segments, k):
    if k is None:
        return segments
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
    arm, arm_source = _arm(args, every)
    mapped = _joint_order(args, arm, every, n)
    if mapped is not None:
        from calibration.joint_map import reorder

        runs = [[reorder(s, *mapped) for s in run] for run in runs]
        held = [reorder(s, *mapped) for s in held] if held else None
        every = [s for run in runs for s in run] + (held or [])
    units = every[0].units
    kt = _parse_kt(args.kt, n)
    if not args.model:  # the physics model works in N*m: current through the vendor's constants
        _apply_kt(every, kt)
    train, heldout = split_heldout(runs, held)
    model = _kinematics(arm, every, n)
    cfg = LoopConfig(rel_gain=args.rel_gain, abs_gain=args.abs_gain, max_effects=args.max_effects)
    meta = {"units": every[0].units, "joint_names": list(every[0].joint_names) or None,
            "arm": arm, "arm_source": arm_source,
            "train_runs": [s.name for s in train], "heldout_runs": [s.name for s in heldout],
            "data_source": ", ".join(_short(p) for p in args.inputs) + (
                " | held out: " + ", ".join(_short(p) for p in args.heldout) if args.heldout else "")}
    if (args.known_mass is None) != (args.known_mass_run is None):
        raise UserError("--known-mass and --known-mass-run go together", where="--known-mass",
                        fix="--known-mass KG --known-mass-run RUN.npz (a run with that payload on)")
    if args.known_mass is not None and not args.model:
        raise UserError("--known-mass works around a model with current-per-torque scales",
                        where="--known-mass",
                        fix="add --model next.json (its identified-current prior), or give --kt")
    t0 = time.perf_counter()
    if args.model:
        from calibration.diagnosis.next_loop import diagnose_next

        known = None
        if args.known_mass is not None:
            known = (args.known_mass, [seg for p in args.known_mass_run for seg in load_segments(p)])
            if mapped is not None:
                from calibration.joint_map import reorder

                known = (known[0], [reorder(s, *mapped) for s in known[1]])
        dg, extra = diagnose_next(args.model, train, heldout, cfg, log=print, kinematics=model,
                                  no_arm=args.arm == "none", kt=kt, known_mass=known,
                                  prior_only=args.prior_only, referenced=args.mass_reference != "none")
        meta.update(extra)
    else:
        from calibration.diagnosis.payload import CurrentScale

        basis = _basis(args, model, n, every[0].units)
        meta.update({"basis": basis.describe(), "title": "grey-box physics model"})
        if units == "A" and kt is not None:
            meta["payload_scale"] = CurrentScale(1.0 / kt, "torque constants")
        declared = _declared(args.declared, basis, n) if args.declared else None
        dg = diagnose(basis, train, heldout, cfg, log=print, declared=declared)
    meta["seconds"] = round(time.perf_counter() - t0, 2)
    rep = write(dg, Path(args.out), meta, plots=not args.no_plots)
    print(rep["headline"])
    print(f"{rep['verdict']}")
    print(f"report: {Path(args.out) / 'report.md'}")
    return 0
