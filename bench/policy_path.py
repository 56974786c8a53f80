"""How much of the code base one demonstration crosses on its way to the wire (#36): the project modules whose
functions run, and their lines, in each stage of the policy path on the twin (SIMULATED, lockstep):

    collect  teleop tick -> recording (one scripted episode, `factr2 collect --no-cameras`)
    train    recording -> labels -> training samples -> checkpoint (`factr2 train --obs state`, 20 steps)
    rollout  checkpoint -> observation -> chunk -> follower command at the wire (`factr2 rollout`, 1 episode)

    python -m bench.policy_path --out DIR [--json FILE]

A module counts when one of its functions is called (sys.setprofile on every thread, the child processes
of the recorder and the cameras not included); "hops" = modules per stage, "lines" = their lines in total.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("hardware", "calibration", "policies", "factr2_teleop")


def _traced(argv: list[str]) -> set[str]:
    from factr2_teleop.cli import main

    seen: set[str] = set()
    roots = tuple(str(REPO / p) + "/" for p in PACKAGES)

    def prof(frame, event, arg):
        if event == "call":
            f = frame.f_code.co_filename
            if f.startswith(roots):
                seen.add(f)

    threading.setprofile(prof)
    sys.setprofile(prof)
    try:
        rc = main(argv)
    finally:
        sys.setprofile(None)
        threading.setprofile(None)
    if rc not in (0, None):
        raise SystemExit(f"{argv[0]} failed ({rc})")
    return {str(Path(f).relative_to(REPO)) for f in seen}


def _lines(mods) -> int:
    return sum(len((REPO / m).read_text().splitlines()) for m in mods)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    o = a.out
    stages = {
        "collect": ["collect", "--task", "peg-insert", "--episodes", "1", "--out", str(o / "col"),
                    "--seed", "0", "--mode", "dob", "--no-cameras"],
        "train": ["train", str(o / "col"), "--out", str(o / "run"), "--obs", "state", "--steps", "20",
                  "--seed", "0", "--threads", "1", "--no-progress", "--include-failed"],
        "rollout": ["rollout", "--policy", str(o / "run"), "--task", "peg-insert", "--episodes", "1",
                    "--seed", "7", "--max-seconds", "2"],
    }
    res, union = {}, set()
    for name, argv in stages.items():
        mods = _traced(argv)
        union |= mods
        res[name] = {"modules": len(mods), "lines": _lines(mods), "files": sorted(mods)}
    res["path"] = {"modules": len(union), "lines": _lines(union), "files": sorted(union)}
    for name, r in res.items():
        print(f"{name:8s} {r['modules']:4d} modules  {r['lines']:6d} lines")
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
