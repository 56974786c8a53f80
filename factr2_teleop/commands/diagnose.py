"""`factr2 diagnose`: fit a grey-box model to logs, trace its held-out residual to missing effects, add them.

    factr2 diagnose run1.npz run2.npz run3.npz --out diag/                 # data-only basis
    factr2 diagnose runs/*.npz --heldout other.npz --arm piper --out diag/  # pinocchio regressor of the arm
    factr2 diagnose runs/*.npz --model next.ckpt --out diag/                # around a trained NEXT model
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
                   "regressor as the rigid part; 'pinocchio-sample' = pinocchio's sample manipulator")
    p.add_argument("--kt", help="torque constants N*m/A per joint, comma separated (current logs with --arm)")
    p.add_argument("--heldout", nargs="+", metavar="FILE", help="held-out runs (default: the last INPUT, or "
                   "the last quarter of a single INPUT)")
    p.add_argument("--out", required=True, help="output folder for report.json, report.md and plots")
    p.add_argument("--rel-gain", type=float, default=0.02, help="minimum relative held-out L1 gain (0.02)")
    p.add_argument("--abs-gain", type=float, default=0.005,
                   help="minimum absolute gain as a fraction of the joint's held-out RMS target (0.005)")
    p.add_argument("--prior-weight", type=float, default=1.0,
                   help="with --arm: ridge weight pulling base parameters toward the description's (1.0)")
    p.add_argument("--max-effects", type=int, default=20)
    p.add_argument("--declared", metavar="REPORT.json",
                   help="effects already known (a first pass: the `effects` of an earlier report.json); "
                        "fitted from the start, not counted as found")
    p.add_argument("--no-plots", action="store_true")


def _basis(args, n: int, units: str):
    from calibration.diagnosis.basis import DataBasis, PinocchioBasis

    if not args.arm:
        return DataBasis(n)
    if args.arm == "pinocchio-sample":
        import pinocchio as pin

        model = pin.buildSampleModelManipulator()
    else:
        try:
            from hardware.arms import load_arm
        except ImportError:
            raise UserError("arm descriptions are not installed", where="--arm",
                            fix="drop --arm to use the data-only basis") from None
        model = load_arm(args.arm).pinocchio_model()
    if model.nv != n:
        raise UserError(f"the arm has {model.nv} joints, the logs {n}", where="--arm",
                        fix="pick the arm the logs were recorded on")
    if units != "N*m":
        raise UserError("logs are in current [A]; the arm's regressor is in N*m", where="--arm",
                        fix="pass --kt K1,K2,... (N*m/A per joint), or drop --arm for the data-only basis")
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
            s.y, s.units = s.y * k, "N*m"
    return segments


def _declared(path: str, basis, n: int) -> list:
    """The `effects` of an earlier report.json as declared effects (their coefficients are refitted)."""
    import json

    from calibration.diagnosis.effects import Effect

    fix = "pass the report.json an earlier `factr2 diagnose` wrote"
    try:
        items = json.loads(Path(path).read_text())["effects"]
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
    cfg = LoopConfig(rel_gain=args.rel_gain, abs_gain=args.abs_gain, max_effects=args.max_effects)
    meta = {"units": every[0].units, "joint_names": list(every[0].joint_names) or None,
            "train_runs": [s.name for s in train], "heldout_runs": [s.name for s in heldout],
            "data_source": ", ".join(_short(p) for p in args.inputs) + (
                " | held out: " + ", ".join(_short(p) for p in args.heldout) if args.heldout else "")}
    t0 = time.perf_counter()
    if args.model:
        from calibration.diagnosis.next_loop import diagnose_next

        dg, extra = diagnose_next(args.model, train, heldout, cfg, log=print)
        meta.update(extra)
    else:
        basis = _basis(args, n, every[0].units)
        meta.update({"basis": basis.describe(), "title": "grey-box physics model"})
        declared = _declared(args.declared, basis, n) if args.declared else None
        dg = diagnose(basis, train, heldout, cfg, log=print, declared=declared)
    meta["seconds"] = round(time.perf_counter() - t0, 2)
    rep = write(dg, Path(args.out), meta, plots=not args.no_plots)
    print(f"{rep['verdict']}")
    print(f"report: {Path(args.out) / 'report.md'}")
    return 0
