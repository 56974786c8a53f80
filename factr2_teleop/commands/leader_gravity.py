"""`factr2 leader-gravity --rig R`: identify a leader's gravity terms (hold poses, least squares) and store
them where teleop reads them, with the residual at rest before and after (calibration/leader_gravity.py).

On a simulated rig the twin runs in lockstep (as fast as the CPU goes); on a real rig the leader moves itself
through the poses in real time: keep hands and cables clear. Teleop, the demo and the terminal app then use
the fitted g(q) for that leader (factr2_teleop.teleop.leader_law.leader_gravity_path says where it lives).
"""

from __future__ import annotations

import json
from pathlib import Path

HELP = "identify a leader arm's gravity compensation (hold a few poses; before/after residual at rest)"


def add_arguments(parser) -> None:
    parser.add_argument("--rig", default="sim-piper",
                        help="rig name or path to a rig .toml (default: sim-piper)")
    parser.add_argument("--leader", default=None, help="leader name in the rig (default: every leader)")
    parser.add_argument("--poses", type=int, default=12, help="poses the fit uses (default 12)")
    parser.add_argument("--check-poses", type=int, default=6,
                        help="further poses that only measure the residual before/after (default 6)")
    parser.add_argument("--seed", type=int, default=None,
                        help="twin noise seed (default: the rig's; the true body is the rig's own)")
    parser.add_argument("--out", default=None,
                        help="write the identification here instead of where teleop reads it")
    parser.add_argument("--json", default=None, metavar="FILE", help="also write the report as JSON")


def run(args) -> int:
    from calibration.leader_gravity import HoldGains, identify, save
    from factr2_teleop.teleop.leader_law import leader_gravity_path
    from hardware.arms import load_arm
    from hardware.connect import open_rig
    from hardware.errors import UserError
    from hardware.rigs import load_rig

    if args.poses < 3 or args.check_poses < 1:
        raise UserError("too few poses", where="--poses / --check-poses",
                        fix="use at least 3 fit poses and 1 check pose")
    rig = load_rig(args.rig)
    names = [d.name for d in rig.leaders]
    if not names:
        raise UserError("the rig has no leader", where=str(rig.path),
                        fix="pick a rig with a [[leaders]] table")
    if args.leader is not None and args.leader not in names:
        raise UserError(f"no leader {args.leader!r}", where="--leader", fix=f"use one of {', '.join(names)}")
    todo = [args.leader] if args.leader else names
    if args.out and len(todo) > 1:
        raise UserError("--out names one file", where="--out", fix="pass --leader too")
    label = "SIMULATED twin" if rig.simulated else "real leader: it moves by itself, keep clear"
    report = {}
    with open_rig(rig, clock="lockstep" if rig.simulated else "realtime", seed=args.seed) as s:
        seed = s.twin.seed if s.twin is not None else None
        for name in todo:
            arm = load_arm(rig.device(name).arm)
            print(f"{name}: holding {args.poses + args.check_poses} poses ({label}) ...", flush=True)
            lg = identify(s.leaders[name], s.clock, arm, n_fit=args.poses, n_check=args.check_poses,
                          gains=HoldGains(), progress=lambda k, n: print(f"  pose {k}/{n}", flush=True))
            lg.meta.update(rig=rig.name, leader=name, twin_seed=seed,
                           body_seed=rig.twin.seed if rig.simulated else None, simulated=rig.simulated,
                           description_error=bool(rig.simulated and rig.twin.description_error))
            path = Path(args.out) if args.out else leader_gravity_path(rig, name)
            save(path, lg)
            _print(name, lg, path)
            report[name] = {**lg.to_json(), "file": str(path)}
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


def _print(name: str, lg, path: Path) -> None:
    b, a = lg.before, lg.after
    n = len(b["rms_nm"])
    print(f"{name}: residual at rest on {lg.meta['poses_check']} check poses (fit on {lg.meta['poses_fit']}, "
          f"{lg.meta['poses_dropped']} not held) [N*m]")
    print("  joint        " + " ".join(f"{f'J{j + 1}':>7s}" for j in range(n)) + "     mean")
    print("  RMS before   " + " ".join(f"{v:7.4f}" for v in b["rms_nm"]) + f"  {b['rms_mean_nm']:7.4f}")
    print("  RMS after    " + " ".join(f"{v:7.4f}" for v in a["rms_nm"]) + f"  {a['rms_mean_nm']:7.4f}")
    print(f"  max |r| before {b['max_nm_all']:.4f}, after {a['max_nm_all']:.4f}")
    print(f"  written: {path} (teleop, the demo and the terminal app use it for this leader)")
