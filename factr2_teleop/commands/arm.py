"""`factr2 arm import FILE.urdf --name NAME [--total-mass KG]`: an arm this project has never seen, from its
vendor URDF (hardware/arms/urdf.py, urdf_import.py; docs/arms_import.md). `factr2 arm list`: built-in and
imported.

The import reads the URDF with pinocchio and with MuJoCo's compiler, checks it (positive masses, physical
inertias, limits, pinocchio and MuJoCo agreeing on gravity and inverse dynamics, the CAD masses against a
stated total), prints what it found and writes the description, its table scene and a GELLO-style leader
(gello_NAME) into the user's arm folder ($FACTR2_ARMS, default ~/.config/factr2/arms). From then on NAME
works wherever an arm is named (--arm, rig files). A file it cannot use: one line, exit 2.
"""

from __future__ import annotations

from pathlib import Path

HELP = "import an arm from its vendor URDF (checked; written to the user's arm folder) or list the arms"


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="arm_command", metavar="ACTION")
    imp = sub.add_parser("import", help="check a URDF and write it as an arm description")
    imp.add_argument("urdf", help="the arm's URDF file (meshes are not needed)")
    imp.add_argument("--name", required=True, help="the arm's name from now on (lower case, e.g. ur5)")
    imp.add_argument("--total-mass", type=float, default=None, metavar="KG",
                     help="the arm's stated mass [kg]: the CAD masses are checked against it")
    imp.add_argument("--armature", default=None, metavar="KG_M2",
                     help="reflected rotor inertia [kg*m^2]: one value or one per joint, comma-separated "
                          "(a URDF has none; default 0)")
    imp.add_argument("--q-home", default=None, metavar="RAD",
                     help="home pose [rad], one value per joint, comma-separated (default: 0 clipped into "
                          "each joint's range; the twin starts there)")
    imp.add_argument("--force", action="store_true", help="replace an arm of that name already imported")
    sub.add_parser("list", help="the built-in arms and those imported into the user's arm folder")


def _numbers(text: str, flag: str, n: int, example: str) -> list[float]:
    """A comma-separated list of one or n finite numbers (UserError naming the flag otherwise)."""
    from hardware.errors import UserError

    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) not in (1, n) or not all(abs(v) < float("inf") for v in vals):
        raise UserError(f"{flag} {text!r}: expected one number or {n}, comma-separated", where=flag,
                        fix=f"e.g. {flag} {example}")
    return vals * n if len(vals) == 1 else vals


def run(args) -> int:
    from hardware.arms import list_arms, user_arms
    from hardware.arms.urdf_import import user_arms_dir

    if args.arm_command == "list":
        print("built-in:", " ".join(list_arms()))
        print(f"imported ({user_arms_dir()}):", " ".join(user_arms()) or "none")
        return 0
    if args.arm_command != "import":
        print("usage: factr2 arm {import,list} ... (factr2 arm --help)")
        return 2
    return _import(args)


def _import(args) -> int:
    from dataclasses import replace

    import numpy as np

    from hardware.arms import load_arm
    from hardware.arms.urdf import UrdfError, read_urdf
    from hardware.arms.urdf_import import (
        AGREE_TOL,
        agreement,
        check,
        check_name,
        to_spec,
        user_arms_dir,
        write_arm,
    )

    check_name(args.name)
    path = Path(args.urdf)
    if not path.is_file():
        raise UrdfError("URDF file not found", where=str(path), fix="give the path to the arm's .urdf")
    if args.total_mass is not None and not args.total_mass > 0:
        raise UrdfError(f"--total-mass {args.total_mass} kg", where="--total-mass",
                        fix="give the arm's mass > 0")
    folder = user_arms_dir()
    if (folder / f"{args.name}.xml").exists() and not args.force:
        raise UrdfError(f"arm '{args.name}' already imported", where=str(folder / f"{args.name}.xml"),
                        fix="pick another --name, or --force to replace it")
    arm = read_urdf(path)
    findings = check(arm, args.total_mass)
    print(f"{path.name}: robot '{arm.robot}', joints {' '.join(j.name for j in arm.joints)}")
    for level, text in findings:
        print(f"  [{level}] {text}")
    errors = [t for lv, t in findings if lv == "error"]
    if errors:
        raise UrdfError(f"{len(errors)} problem(s), first: {errors[0]}", where=str(path),
                        fix="correct the URDF's inertials and limits (each problem listed above)")
    n = len(arm.joints)
    armature = 0.0 if args.armature is None else _numbers(args.armature, "--armature", n, "0.01")
    if np.any(np.asarray(armature) < 0):
        raise UrdfError("--armature below 0", where="--armature", fix="give kg*m^2 >= 0")
    spec = to_spec(arm, args.name, armature)
    if args.q_home is not None:
        home = _numbers(args.q_home, "--q-home", n, "0,-1.57,1.57,-1.57,-1.57,0")
        if any(not lk.range[0] <= h <= lk.range[1] for h, lk in zip(home, spec.links)):
            raise UrdfError("--q-home outside the joint limits", where="--q-home",
                            fix="give a pose inside every joint's range [rad]")
        spec = replace(spec, q_home=tuple(home))
    paths = write_arm(spec, folder)
    try:
        desc = load_arm(args.name)
        worst = agreement(path, desc)
    except Exception:
        for p in paths:
            p.unlink(missing_ok=True)
        raise
    for key, val in worst.items():
        print(f"  [{'ok' if val <= AGREE_TOL else 'error'}] {key.replace('_', ' ')}: max relative "
              f"difference {val:.1e} (20 random states)")
    if max(worst.values()) > AGREE_TOL:
        for p in paths:
            p.unlink(missing_ok=True)
        raise UrdfError(f"pinocchio, MuJoCo and the description disagree ({max(worst.values()):.1e} > "
                        f"{AGREE_TOL:g})", where=str(path),
                        fix="report the file: the conversion lost something")
    for p in paths:
        print(f"wrote {p}")
    print(f"use it as --arm {args.name}, arm = \"{args.name}\" in a rig file; leader: gello_{args.name}")
    return 0
