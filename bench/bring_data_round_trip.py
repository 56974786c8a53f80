"""Round trip of docs/bringing_data.md: our recordings -> `factr2 export lerobot` -> the samples `factr2
train` makes of that dataset, against the samples it makes of the recordings themselves: counts and a SHA-256
of the first batch (every tensor the model gets). Both go through policies.training.run.prepare,
`factr2 train`'s own data path, with the same flags.

    python -m bench.bring_data_round_trip [RECORDING_OR_DIR] [-- TRAIN FLAGS]

Default input: a synthetic state-only twin-style recording (tests/policy_helpers.py); flags default to
`--obs state` (a twin task recording without cameras: `factr2 collect --no-cameras`; default thresholds: the
dataset's own phase column is trained on). Given --thresholds are passed to the export as well.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from factr2_teleop.cli import build_parser, main
from policies.training.run import prepare
from policies.training.run_config import from_args
from policies.training.train import setup_distributed

ROOT = Path(__file__).resolve().parents[1]


def digest(data, n: int = 64) -> str:
    b = data.batch(np.arange(min(n, len(data))))
    h = hashlib.sha256()
    for k in sorted(b):
        h.update(k.encode())
        h.update(b[k].numpy().tobytes())
    return h.hexdigest()[:16]


def samples(inputs, out: Path, flags: list[str]):
    ns = build_parser().parse_args(["train", str(inputs), "--out", str(out), *flags])
    data, *_ = prepare(from_args(ns).resolved(), setup_distributed())
    return data


def main_(argv: list[str]) -> int:
    if argv[:1] in (["-h"], ["--help"]):
        print(__doc__)
        return 0
    src, flags = (argv[:1], argv[2:]) if argv and argv[0] != "--" else ([], argv[1:])
    flags = flags or ["--obs", "state"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        os.environ.setdefault("FACTR2_CACHE", str(tmp / "cache"))
        if src:
            rec = Path(src[0])
        else:
            from tests.policy_helpers import write_recording

            rec = write_recording(tmp / "rec.mcap", episodes=4, seconds=6.0, cameras=(), objects=3)
        th = [f for f in flags if f.startswith("--thresholds")] and flags[flags.index("--thresholds"):][:2]
        assert main(["export", "lerobot", str(rec), "--out", str(tmp / "ds"), *th]) == 0
        a = samples(rec, tmp / "r1", flags)
        b = samples(tmp / "ds", tmp / "r2", flags)
        tr_a, tr_b = a.split()[0], b.split()[0]
        print(f"recordings: {len(a)} samples ({len(tr_a)} train), first batch sha256 {digest(a)}")
        print(f"LeRobot   : {len(b)} samples ({len(tr_b)} train), first batch sha256 {digest(b)}")
        keys = ("state", "force", "action", "mask", "phase", "objects")
        eq = {k: len(a) == len(b) and np.array_equal(getattr(a, k), getattr(b, k)) for k in keys}
        print("equal per sample:", ", ".join(f"{k} {'yes' if v else 'no'}" for k, v in eq.items()))
        if len(a) == len(b) and not eq["phase"]:  # labels made again from the dataset's force column
            sa, sb = (np.bincount(d.phase, minlength=3) / len(d) for d in (a, b))
            print(f"phase agreement {np.mean(a.phase == b.phase):.2%}; shares F/PC/C {sa} vs {sb}")
        return 0 if all(eq.values()) and digest(a) == digest(b) else 1


if __name__ == "__main__":
    sys.exit(main_(sys.argv[1:]))
