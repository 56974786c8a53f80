"""The factr2 MCAP recording format: topics, message schemas (with units), payload codecs.

Numeric channels are JSON (message encoding "json", JSON-schema schemas Foxglove can plot); NaN is written as
null. Camera frames are foxglove.CompressedImage in protobuf (hand-written descriptor, see protobuf_wire.py).
Every numeric payload carries `t` [s] on the rig clock (monotonic or simulated); an MCAP log_time is
`round(t * 1e9) + round(clock_offset_s * 1e9)` ns, with clock_offset_s (wall time minus rig time at the
start) in the recording metadata, so Foxglove shows wall-clock times. docs/recording.md lists everything here.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

import numpy as np

from hardware.recording.protobuf_wire import IMAGE_SCHEMA_NAME, compressed_image_descriptor_set

PROFILE = "factr2"
FORMAT_VERSION = 1
# MCAP metadata record name of the recording metadata (rig, arms, software, operator ...; metadata.py). The
# name is part of the file format: every recording written so far has it, and readers look for it.
RECORDING_METADATA = "factr2.session"
STATS_METADATA = "factr2.recorder_stats"  # written on a clean close only

TOPIC_EVENTS = "/events"
TOPIC_LOOP = "/loop/timing"
# PRIVILEGED (twins only): the task objects' state as one flat vector (policies/data/privileged.py builds it);
# read back as this feature name, a policy input in place of camera frames (`factr2 train --obs state`)
TOPIC_TASK_OBJECTS = "/task/objects"
TASK_OBJECTS_FEATURE = "observation.state.objects"
# SIMULATED (twins only), not privileged: the task objects as a simulated camera pose detector reports them
# (hardware/sim/perception.py seen_vector: pose, visible, age per object), recorded live as the demonstrator
# or the policy saw them; read back as this feature name (`factr2 train --obs perceived`)
TOPIC_PERCEIVED = "/perceived/objects"
PERCEIVED_FEATURE = "observation.perceived.objects"
OBJECT_TOPICS = {TASK_OBJECTS_FEATURE: TOPIC_TASK_OBJECTS, PERCEIVED_FEATURE: TOPIC_PERCEIVED}  # by feature
# a policy rollout with operator takeover (issue #33): who drives the follower, written when it changes (and
# at each episode's start), so a tick's driver is the latest value at or before it (previous-value hold)
TOPIC_ROLLOUT_DRIVER = "/rollout/driver"
DRIVER_POLICY, DRIVER_OPERATOR = 0, 1  # the `driver` field's codes
DRIVER_NAMES = ("policy", "operator")


def joint_state_topic(arm: str) -> str:
    return f"/{arm}/joint_state"


def tau_ext_topic(arm: str) -> str:
    return f"/{arm}/tau_ext"


def tau_cmd_topic(arm: str) -> str:
    return f"/{arm}/tau_cmd"


def command_topic(arm: str) -> str:
    return f"/{arm}/command"


def perturb_topic(arm: str) -> str:
    """A perturbed collection's offsets on the follower's target (PERTURBATION)."""
    return f"/{arm}/perturb"


def ground_truth_topic(arm: str) -> str:
    return f"/{arm}/ground_truth"


def camera_topic(camera: str) -> str:
    return f"/camera/{camera}/image"


def camera_name(topic: str) -> str:
    return topic.split("/")[2] if topic.startswith("/camera/") else topic


# Event kinds on /events. An episode runs from "start" to "stop"; "success"/"failure"/"discard" label it
# (they may come after the stop); "progress" is a task-progress mark (value in [0, 1]); "note" is free text.
# "takeover" / "handback" mark an operator's intervention in a rollout (text: JSON {"by": "hand" | "key" |
# "fault" | "episode end", "pre_window_s": the pre-intervention window [s]}, value: the hand torque [N*m])
EVENT_KINDS = ("start", "stop", "success", "failure", "discard", "progress", "note", "takeover", "handback")
TAKEOVER_KINDS = ("takeover", "handback")
OUTCOME_KINDS = ("success", "failure", "discard")


@dataclass(frozen=True)
class Field:
    """One payload field. kind: "float" (linear interpolation when resampled), "bool"/"int" (previous-value
    hold). vector: one value per joint (else scalar or fixed-length `size`). feature: flat signal name
    under the arm prefix (LeRobot-like, matching JointState.features())."""

    name: str
    unit: str
    kind: str
    vector: bool
    feature: str
    doc: str


@dataclass(frozen=True)
class Schema:
    name: str
    doc: str
    fields: tuple[Field, ...]

    def json_schema(self) -> dict:
        props: dict[str, dict] = {"t": {"type": "number", "description": "rig clock time [s]"}}
        for f in self.fields:
            base = {"float": {"type": ["number", "null"]}, "bool": {"type": "boolean"},
                    "int": {"type": "integer"}}[f.kind]
            desc = f"{f.doc} [{f.unit}]" if f.unit else f.doc
            props[f.name] = ({"type": "array", "items": base, "description": desc} if f.vector
                             else dict(base, description=desc))
        return {"title": self.name, "description": self.doc, "type": "object", "properties": props}

    def schema_bytes(self) -> bytes:
        return json.dumps(self.json_schema()).encode()


def _f(name, unit, kind, vector, feature, doc):
    return Field(name, unit, kind, vector, feature, doc)


JOINT_STATE = Schema("factr2.JointState", "one joint-state sample of an arm at loop rate", (
    _f("q", "rad", "float", True, "joint.pos", "joint position"),
    _f("q_dot", "rad/s", "float", True, "joint.vel", "joint velocity"),
    _f("tau_m", "N*m", "float", True, "joint.tau", "measured motor torque (current x torque constant)"),
    _f("current", "A", "float", True, "joint.current", "motor current"),
    _f("q_cmd", "rad", "float", True, "joint.pos_cmd", "last commanded joint target (null: none)"),
    _f("temperature", "degC", "float", True, "joint.temp", "motor temperature"),
    _f("status", "", "int", True, "joint.status", "STATUS_* bit flags (hardware/types.py)"),
    _f("gripper_pos", "m or rad", "float", False, "gripper.pos", "gripper stroke or leader trigger"),
    _f("gripper_effort", "N*m or N", "float", False, "gripper.effort", "gripper effort as reported"),
))
EXTERNAL_TORQUE = Schema("factr2.ExternalTorque", "estimated external joint torque and contact state", (
    _f("tau_ext", "N*m", "float", True, "joint.tau_ext", "estimated external torque"),
    _f("contact", "", "bool", False, "contact", "contact detected (hysteresis output)"),
))
TORQUE_COMMAND = Schema("factr2.TorqueCommand", "torque commanded to an arm (leader force feedback)", (
    _f("tau", "N*m", "float", True, "joint.tau_cmd", "commanded joint torque after the safety layer"),
    _f("gate", "", "float", False, "feedback_gate", "force-feedback gate in [0, 1] (null: not used)"),
))
FOLLOWER_COMMAND = Schema("factr2.FollowerCommand",
                          "position target sent to a follower, as it left the safety layer (the action)", (
    _f("q", "rad", "float", True, "joint.pos", "joint position target after the safety layer"),
    _f("gripper", "m", "float", False, "gripper.pos", "gripper stroke target (null: none sent)"),
    _f("hold", "", "bool", False, "hold", "the safety layer turned this command into a hold"),
))
GROUND_TRUTH = Schema("factr2.GroundTruth", "twin ground truth (simulated: only recorded on a twin)", (
    _f("tau_ext_true", "N*m", "float", True, "joint.tau_ext_true", "true external joint torque"),
    _f("contact", "", "bool", False, "contact_true", "any contact on the arm"),
    _f("force", "N", "float", True, "force_true", "net contact force on the arm, world frame (x, y, z)"),
))
LOOP_TIMING = Schema("factr2.LoopTiming", "control-loop timing of one sampled tick", (
    _f("period_s", "s", "float", False, "period", "time since the previous tick"),
    _f("busy_s", "s", "float", False, "busy", "wall time the loop spent inside the previous tick"),
    _f("late_s", "s", "float", False, "late", "how late this tick started versus its deadline"),
    _f("overruns", "", "int", False, "overruns", "ticks that missed their deadline so far"),
))
TASK_OBJECTS = Schema(
    "factr2.TaskObjects",
    "PRIVILEGED, twin only (simulated): the task objects' state, flattened in the order the channel's "
    "`names` metadata lists (policies/data/privileged.py); never available on real hardware",
    (_f("objects", "m, rad, 1 or N (per element: see names)", "float", True, "objects",
        "object poses [m] (positions), rotation-matrix entries [1], yaws [rad], finger contacts (0/1), "
        "contact force [N]"),),
)
PERCEIVED_OBJECTS = Schema(
    "factr2.PerceivedObjects",
    "SIMULATED, twin only: the task objects as a simulated camera pose detector reports them (calibration "
    "bias, noise, rate, latency, occlusion; hardware/sim/perception.py), flattened in the order the "
    "channel's `names` metadata lists",
    (_f("objects", "m, 1 or s (per element: see names)", "float", True, "objects",
        "perceived positions [m], rotations (first two columns) [1], visible (0/1), detection age [s]"),),
)
ROLLOUT_DRIVER = Schema("factr2.RolloutDriver", "who drives the follower in a rollout, from this tick on "
                        "(written on a change only)", (
    _f("driver", "", "int", False, "driver", "0 = the policy, 1 = the operator through the leader"),
    _f("hand_nm", "N*m", "float", False, "hand_torque", "the hand's torque on the leader at the change"),
))
PERTURBATION = Schema("factr2.Perturbation", "a perturbed collection (DART-style, `factr2 collect "
                      "--perturb`): the offset added to the operator's follower target before the safety "
                      "layer, every tick of an episode (zeros outside the perturbation windows)", (
    _f("offset", "rad", "float", True, "joint.perturb", "offset added to the joint target"),
))
NUMERIC_SCHEMAS: dict[str, Schema] = {s.name: s for s in (JOINT_STATE, EXTERNAL_TORQUE, TORQUE_COMMAND,
                                                           FOLLOWER_COMMAND, GROUND_TRUTH, LOOP_TIMING,
                                                           TASK_OBJECTS, ROLLOUT_DRIVER,
                                                           PERCEIVED_OBJECTS, PERTURBATION)}
EVENT_SCHEMA_NAME = "factr2.Event"
ACTION = "action"  # the arm prefix of the follower's command: the policy's action (hardware/features.py)


def signal_name(topic: str, schema_name: str, feature: str) -> str:
    """Flat name of a recorded numeric field: "<arm>.<feature>", with the follower's command topic named as
    the action ("/follower/command" q -> "action.joint.pos"; "/left_follower/command" -> "left_action..."),
    and the privileged task-object vector as "observation.state.objects"."""
    if schema_name == TASK_OBJECTS.name:
        return TASK_OBJECTS_FEATURE  # not an arm's signal: the policy's privileged state input
    if schema_name == PERCEIVED_OBJECTS.name:
        return PERCEIVED_FEATURE  # the policy's perceived (simulated camera) object input
    arm = topic.split("/")[1]
    if schema_name == FOLLOWER_COMMAND.name:
        arm = arm[: -len("follower")] + ACTION if arm.endswith("follower") else f"{arm}_{ACTION}"
    return f"{arm}.{feature}"



def event_json_schema() -> bytes:
    props = {"t": {"type": "number", "description": "rig clock time [s]"},
             "kind": {"type": "string", "enum": list(EVENT_KINDS)},
             "episode": {"type": "integer", "description": "episode index in this file"},
             "text": {"type": "string", "description": "task name, label or operator note"},
             "value": {"type": ["number", "null"], "description": "task progress in [0, 1] (progress marks)"}}
    return json.dumps({"title": EVENT_SCHEMA_NAME, "description": "episode event", "type": "object",
                       "properties": props}).encode()


def image_schema() -> tuple[str, str, bytes]:
    """(name, encoding, data) of the camera schema."""
    return IMAGE_SCHEMA_NAME, "protobuf", compressed_image_descriptor_set()


# Non-finite numbers as %-formatting writes them, only in value position (after ':', '[' or ',').
_NONFINITE = re.compile(r"(?<=[:\[,])(-?inf|nan)(?=[,\]}])")
_TEMPLATES: dict[tuple, str] = {}


def _template(schema: Schema, key: tuple) -> str:
    parts, i = ['{"t":%r'], 1
    for f in schema.fields:
        spec = {"float": "%.9g", "int": "%d", "bool": "%s"}[f.kind]
        if f.vector:
            parts.append(f'"{f.name}":[' + ",".join([spec] * key[i]) + "]")
            i += 1
        else:
            parts.append(f'"{f.name}":{spec}')
    return ",".join(parts) + "}"


def encode_numeric(schema: Schema, payload: dict) -> bytes:
    """Fast JSON for a numeric schema (one %-format per message, ~3x faster than json.dumps): t exact (repr),
    floats with 9 significant digits (relative error <= 5e-10), NaN/inf as null. Floats must be floats
    (NaN, not None), ints ints, bools bools."""
    vals = [payload["t"]]
    key = [schema.name]
    for f in schema.fields:
        v = payload[f.name]
        if f.vector:
            key.append(len(v))
            vals.extend(v)
        else:
            vals.append(("true" if v else "false") if f.kind == "bool" else v)
    k = tuple(key)
    fmt = _TEMPLATES.get(k)
    if fmt is None:
        fmt = _TEMPLATES[k] = _template(schema, k)
    out = fmt % tuple(vals)
    if "nan" in out or "inf" in out:
        out = _NONFINITE.sub("null", out)
    return out.encode()


def encode_json(payload: dict) -> bytes:
    """JSON payload with NaN/inf as null (JSON has no NaN; Foxglove would reject it)."""
    s = json.dumps(payload, separators=(",", ":"))
    if "NaN" in s or "Infinity" in s:
        s = s.replace("-Infinity", "null").replace("Infinity", "null").replace("NaN", "null")
    return s.encode()


def encode_event(t: float, kind: str, episode: int, text: str = "", value: float = float("nan")) -> bytes:
    v = float(value)
    return json.dumps({"t": float(t), "kind": kind, "episode": int(episode), "text": str(text),
                       "value": v if math.isfinite(v) else None}).encode()


def log_time_ns(t: float, clock_offset_s: float) -> int:
    """MCAP log_time [ns] of a rig-clock time t [s] (never negative)."""
    return max(0, round(float(t) * 1e9) + offset_ns(clock_offset_s))


def offset_ns(clock_offset_s: float) -> int:
    """The clock offset in integer ns: adding in integers keeps log times exact to 1 ns (a float sum at
    ~1.8e9 s would round to ~0.2 us)."""
    return round(float(clock_offset_s) * 1e9)


def rig_time_s(log_time: np.ndarray, clock_offset_s: float) -> np.ndarray:
    """Rig clock time [s] of MCAP log times [ns] (inverse of log_time_ns)."""
    return (np.asarray(log_time, dtype=np.int64) - offset_ns(clock_offset_s)) / 1e9
