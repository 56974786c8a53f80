"""Session metadata written at the start of every recording (MCAP metadata record "factr2.session").

All values are strings (MCAP metadata is str -> str); lists and dicts are JSON.
"""

from __future__ import annotations

import getpass
import hashlib
import json
import platform
import time
from datetime import datetime, timezone
from pathlib import Path

from hardware.recording.schemas import FORMAT_VERSION


def software_version() -> str:
    try:
        from importlib.metadata import version

        return version("factr2-teleop")
    except Exception:  # not installed as a package (a source checkout)
        return "unknown"


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def describe_session(*, rig_path: str | Path | None = None, arm_files: list[str | Path] = (),
                     next_checkpoint: str = "", operator: str | None = None, task: str = "",
                     twin: bool | None = None) -> dict[str, str]:
    """Metadata the app passes to Recorder(metadata=...): the rig file's full text, the SHA-256 of each arm
    description file, the NEXT checkpoint id, the operator, the task, and whether this is a twin."""
    meta: dict[str, str] = {"next_checkpoint": str(next_checkpoint), "task": str(task)}
    if operator is not None:
        meta["operator"] = str(operator)
    if twin is not None:
        meta["simulated"] = "true" if twin else "false"
    if rig_path is not None:
        p = Path(rig_path)
        meta["rig_file"] = str(p)
        meta["rig_toml"] = p.read_text(errors="replace") if p.is_file() else ""
    hashes = {}
    for a in arm_files:
        p = Path(a)
        hashes[p.name] = _sha256(p) if p.is_file() else "missing"
    meta["arm_description_sha256"] = json.dumps(hashes)
    return meta


def session_metadata(*, clock_offset_s: float, joint_names: dict[str, list[str]]) -> dict[str, str]:
    """Defaults every recording gets; Recorder merges the caller's metadata over these."""
    try:
        operator = getpass.getuser()
    except Exception:
        operator = "unknown"
    now = datetime.now(timezone.utc).astimezone()
    return {
        "format_version": str(FORMAT_VERSION),
        "software_version": software_version(),
        "python": platform.python_version(),
        "host": platform.node(),
        "operator": operator,
        "start_time": now.isoformat(timespec="milliseconds"),
        "time_zone": f"{time.strftime('%Z')} (UTC{now.strftime('%z')})",
        "clock_offset_s": repr(float(clock_offset_s)),
        "joint_names": json.dumps(joint_names),
        "next_checkpoint": "",
        "simulated": "unknown",
    }
