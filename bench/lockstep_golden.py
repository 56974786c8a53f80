"""Lockstep outputs of the policy path, dumped as arrays for a bit-for-bit comparison across a refactor (#36).

    python -m bench.lockstep_golden run OUT_DIR          # demo, collect, train, rollout (twin: SIMULATED)
    python -m bench.lockstep_golden compare A.npz B.npz  # every array equal, bit for bit

What is compared: every numeric field and timestamp of every topic in the demo's, the collection's and the
rollout's recordings (the wire commands are the /*/command topics), and every logged training metric at
equal seeds.
Text (events, messages) is not compared: rewording a message is allowed to change it.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np


def _factr2(*args: str) -> None:
    cmd = [sys.executable, "-m", "factr2_teleop.cli", *args]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(args[:1])} failed ({r.returncode}): {r.stderr.strip()[-600:]}")


def _recording_arrays(prefix: str, folder: Path) -> dict[str, np.ndarray]:
    from hardware.recording.reader import Recording

    (path,) = sorted(folder.glob("*.mcap"))
    rec = Recording(path, use_cache=False, write_cache=False)
    out = {}
    for topic in rec.topics:
        ta = rec.topic(topic)
        out[f"{prefix}{topic}:t"] = np.asarray(ta.t)
        for name, a in ta.fields.items():
            a = np.asarray(a)
            if a.dtype.kind in "biuf":
                out[f"{prefix}{topic}:{name}"] = a
    return out


def _metrics(run: Path) -> dict[str, np.ndarray]:
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
    keys = sorted({k for r in rows for k, v in r.items() if isinstance(v, (int, float)) and "time" not in k
                   and not k.endswith("_s") and "per_s" not in k})
    return {f"train:{k}": np.array([r.get(k, np.nan) for r in rows], float) for k in keys}


def run(out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    _factr2("demo", "--headless", "--clock", "lockstep", "--seconds", "3", "--mode", "dob",
            "--record", str(out / "demo"), "--json", str(out / "demo.json"))
    _factr2("collect", "--task", "peg-insert", "--episodes", "2", "--out", str(out / "col"), "--seed", "0",
            "--mode", "dob", "--no-cameras")
    _factr2("train", str(out / "col"), "--out", str(out / "run"), "--obs", "state", "--steps", "40",
            "--seed", "0", "--threads", "1", "--no-progress", "--include-failed")
    _factr2("rollout", "--policy", str(out / "run"), "--task", "peg-insert", "--episodes", "1", "--seed", "7",
            "--record", str(out / "roll"), "--max-seconds", "3", "--json", str(out / "roll.json"))
    arrays = {**_recording_arrays("demo:", out / "demo"), **_recording_arrays("collect:", out / "col"),
              **_metrics(out / "run"), **_recording_arrays("rollout:", out / "roll")}
    np.savez(out / "golden.npz", **arrays)
    print(f"{len(arrays)} arrays -> {out / 'golden.npz'}")
    return out / "golden.npz"


def compare(a_path: Path, b_path: Path) -> int:
    a, b = np.load(a_path), np.load(b_path)
    bad = [k for k in sorted(set(a) | set(b)) if k not in a or k not in b or a[k].shape != b[k].shape
           or a[k].dtype != b[k].dtype or a[k].tobytes() != b[k].tobytes()]
    groups = sorted({k.split(":")[0] for k in a})
    print(f"{len(a)} / {len(b)} arrays ({', '.join(groups)}); {len(bad)} differ")
    for k in bad[:30]:
        print("  differs:", k, a[k].shape if k in a else "missing", b[k].shape if k in b else "missing")
    return 1 if bad else 0


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "run":
        run(Path(sys.argv[2]))
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        sys.exit(compare(Path(sys.argv[2]), Path(sys.argv[3])))
    else:
        sys.exit(__doc__)
