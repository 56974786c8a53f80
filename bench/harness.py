"""What every benchmark shares: the machine it ran on, the commit, and one shape for a result.

A result file is one JSON object (`record()`):

    {"experiment": "faults_soak", "command": "python -m bench.faults_soak --minutes 30 ...",
     "commit": "3396997" (+ "-dirty" when the tree had changes), "date": "2026-...Z" (UTC),
     "machine": machine(), "simulated": true, "payload": {...the script's own numbers...}}

Published results live in results/ (named by experiment, listed by `python -m bench.results_index`); a run
writes to bench/out/ (scratch, git-ignored) unless told otherwise.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"  # published results, committed
OUT = ROOT / "bench" / "out"  # a run's scratch output, git-ignored
SCHEMA = 1


def cpu_model() -> str:
    """The CPU's model name (as `lscpu` says it), from /proc/cpuinfo; the platform's word where absent."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(module: str) -> str | None:
    """A package's version without importing it when it is not already imported (torch costs ~1 s)."""
    mod = sys.modules.get(module)
    if mod is not None:
        return getattr(mod, "__version__", None)
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version(module)
    except (ImportError, PackageNotFoundError):
        return None


def commit() -> str:
    """The repository's short HEAD, '-dirty' when tracked files differ from it; '' outside a git checkout."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                              text=True, timeout=10)
        if head.returncode != 0:
            return ""
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, timeout=10)
        return head.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return ""


def machine() -> dict:
    """The machine and environment a number depends on: CPU model, cores, load (1/5/15 min), OS, and the
    versions of Python, torch, MuJoCo and numpy."""
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "load": [round(x, 2) for x in os.getloadavg()],
            "platform": platform.platform(), "python": platform.python_version(),
            "torch": _version("torch"), "mujoco": _version("mujoco"), "numpy": _version("numpy")}


def machine_line(m: dict | None = None) -> str:
    """machine() as one line, for a printed table."""
    m = m or machine()
    return (f"{m['cpu']}, {m['cores']} cores, load {m['load'][0]:.2f}; Python {m['python']}, "
            f"torch {m['torch']}, MuJoCo {m['mujoco']}, numpy {m['numpy']}")


def command(argv: list[str] | None = None, module: str | None = None) -> str:
    """The command line that reproduces a run: `python -m bench.NAME ARGS`."""
    argv = sys.argv if argv is None else argv
    name = module or Path(argv[0]).stem
    return shlex.join(["python", "-m", name if name.startswith("bench.") else f"bench.{name}", *argv[1:]])


def names(text: str) -> list[str]:
    """A comma-separated option's names, blanks dropped ("a, b,," -> ["a", "b"])."""
    return [x.strip() for x in text.split(",") if x.strip()]


def now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z")


def record(experiment: str, payload, *, simulated: bool, cmd: str | None = None, **extra) -> dict:
    """One result in the shared shape (module docstring). simulated: the numbers come from a twin or an
    emulator (SIMULATED), not from hardware."""
    rec = {"schema": SCHEMA, "experiment": experiment, "command": cmd or command(), "commit": commit(),
           "date": now(), "machine": machine(), "simulated": bool(simulated)}
    rec.update(extra)
    rec["payload"] = payload
    return rec


def is_record(data) -> bool:
    return isinstance(data, dict) and "experiment" in data and "payload" in data


def payload(data):
    """The numbers of a result file: the record's payload."""
    if not is_record(data):
        raise ValueError("not a result record (bench/harness.py): no 'experiment' and 'payload'")
    return data["payload"]


def load(path: str | Path) -> dict:
    """A result file, checked to be a record."""
    data = json.loads(Path(path).read_text())
    if not is_record(data):
        raise SystemExit(f"{path}: not a result record (bench/harness.py): write it with harness.record()")
    return data


def write(path: str | Path, rec: dict) -> Path:
    """Write a record whole or not at all (a killed run leaves the previous file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(rec, indent=1, default=float) + "\n")
    os.replace(tmp, path)
    return path


def write_or_check(path: Path, text: str, check: bool, remake: str) -> int:
    """A file made from results/: written, or with check only compared (exit code 1 and one line saying
    the command that remakes it when it differs, 0 when it is current)."""
    if check:
        if not path.is_file() or path.read_text() != text:
            print(f"{path} is stale: run `{remake}`", file=sys.stderr)
            return 1
        print(f"{path}: current")
        return 0
    path.write_text(text)
    print(f"wrote {path}")
    return 0


def add_quick(ap: argparse.ArgumentParser, what: str) -> None:
    """--quick: the smallest run that goes through the whole script (CI runs it: tests/test_bench_quick.py).
    what: what the quick run does, for --help."""
    ap.add_argument("--quick", action="store_true", help=f"a few-second smoke run ({what}); its numbers "
                                                        "mean nothing")
