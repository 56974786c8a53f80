"""Recording metadata: the record written at the start of every recording (rig, arms, software, operator,
clock offset, joint names, ...). On disk it is the MCAP metadata record named "factr2.session"
(schemas.RECORDING_METADATA): the name is part of the file format, kept so that every recording already
written, and every reader already deployed, stays valid.

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


def arm_metadata(rig) -> dict[str, dict]:
    """Per device of a rig (hardware.rigs.rig.Rig): its arm description's name, the SHA-256 of that file,
    its joint names and role -- what a reader needs to know which arm a recorded joint state comes from."""
    from hardware.arms import load_arm

    out = {}
    for dev in list(rig.leaders) + list(rig.followers):
        desc = load_arm(dev.arm)
        out[dev.name] = {"arm": desc.name, "arm_sha256": desc.sha256, "joint_names": list(desc.joint_names),
                         "role": dev.role}
    return out


def recorded_arm(meta: dict[str, str], label: str) -> dict:
    """The arm entry (arm_metadata) of the recorded arm `label` ("follower", "left_follower", ...) in a
    recording's metadata (Recording.info): the device of that name, else the one arm shared by every
    device whose role ends the label ("follower", "leader"); {} when the recording does not say."""
    try:
        arms = json.loads(meta.get("arms", "") or "{}")
    except ValueError:
        return {}
    if label in arms:
        return arms[label]
    same_role = {json.dumps(a, sort_keys=True) for a in arms.values() if label.endswith(a.get("role", "?"))}
    return json.loads(same_role.pop()) if len(same_role) == 1 else {}


def describe_recording(*, rig_path: str | Path | None = None, arm_files: list[str | Path] = (),
                     next_checkpoint: str = "", operator: str | None = None, task: str = "",
                     twin: bool | None = None, arms: dict[str, dict] | None = None) -> dict[str, str]:
    """Metadata the app passes to Recorder(metadata=...): the rig file's full text, the SHA-256 of each arm
    description file, the NEXT checkpoint id, the operator, the task, whether this is a twin, and `arms`
    (arm_metadata: per device its arm name, description hash and joint names; read from the rig file when
    not given, so every recording says which arm it comes from)."""
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
    if arms is None and rig_path is not None and Path(rig_path).is_file():
        from hardware.errors import ConfigError
        from hardware.rigs.rig import load_rig

        try:
            arms = arm_metadata(load_rig(rig_path))
        except ConfigError:  # the recording still starts; it just cannot name its arms
            arms = None
    if arms is not None:
        meta["arms"] = json.dumps(arms)
    return meta


def default_metadata(*, clock_offset_s: float, joint_names: dict[str, list[str]]) -> dict[str, str]:
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
