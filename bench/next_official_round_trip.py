"""Round trip of docs/bringing_data.md: an H5 file in the official NEXT schema -> `factr2 calibrate
--from-logs` -> our checkpoint -> `factr2 export next-official` -> loaded back: the largest difference of the
offline estimates on the file's last episode, without and with a gate (folded into the official head).

    python -m bench.next_official_round_trip [FILE.h5::ARM]

Default input: an H5 file written to the published schema (tests/next_h5_helpers.py: 3 episodes of 30, 24
and 18 s at 50 Hz, arms left and right); its last episode is the one scored.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from calibration.next.checkpoint import load_checkpoint
from calibration.next.estimator import batch_tau_f
from calibration.next.logs import read_logs
from calibration.next.official import write_official
from factr2_teleop.cli import main

ROOT = Path(__file__).resolve().parents[1]


def max_diff(a_ck, b_ck, log) -> tuple[float, int]:
    a = batch_tau_f(a_ck, log.q, log.qd, log.q_cmd, tau=log.tau)
    b = batch_tau_f(b_ck, log.q, log.qd, log.q_cmd, tau=log.tau)
    ok = np.isfinite(a).all(1)
    return float(np.abs(a[ok] - b[ok]).max()), int(ok.sum())


def run(h5: str) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if not h5:
            from tests.next_h5_helpers import write_next_h5

            h5 = f"{write_next_h5(tmp / 'free.h5', lengths=(1500, 1200, 900), arms=('left', 'right'))}::left"
        cmd = ["calibrate", "--from-logs", h5, "--out", str(tmp / "cal"), "--prior", "none",
               "--rate-hz", "50", "--max-seconds", "20", "--no-plots"]
        print("factr2 " + " ".join(cmd))
        assert main(cmd) == 0
        assert main(["export", "next-official", str(tmp / "cal" / "next.json"), "--out",
                     str(tmp / "off")]) == 0
        ours, back = load_checkpoint(tmp / "cal" / "next.json"), load_checkpoint(tmp / "off")
        log = read_logs(h5, ours.rate_hz)[-1].log
        d, n = max_diff(ours, back, log)
        print(f"no gate: max |ours - official layout| {d:.3g} N*m over {n} estimates x "
              f"{len(ours.joint_names)} joints")
        rng = np.random.default_rng(0)
        ours.model.set_gate(rng.uniform(0.3, 1.0, len(ours.joint_names)).tolist(),
                            rng.normal(0, 0.2, len(ours.joint_names)).tolist())
        write_official(ours, tmp / "off_gate")
        d_g, _ = max_diff(ours, load_checkpoint(tmp / "off_gate"), log)
        print(f"gate folded: max |ours - official layout| {d_g:.3g} N*m")
        return 0 if max(d, d_g) <= 1e-6 else 1


if __name__ == "__main__":
    sys.exit(run(sys.argv[1] if len(sys.argv) > 1 else ""))
