"""Rig files: which leaders and followers a setup has, how to reach them, and (for twins) how to simulate
them.

A rig is a TOML file (built-in ones live next to this module; see docs/twin.md for the format):

    [rig]            name, description, simulated (true: a MuJoCo twin serves the buses)
    [[leaders]]      driver (a leader kind: "dynamixel"), arm, + the kind's config fields (port, ...),
                     [leaders.limits], [leaders.twin]
    [[followers]]    driver (a follower kind: "piper" | "damiao" | "sim"), arm, + the kind's config fields
                     (channel, ...), next_checkpoint, [followers.limits], [followers.twin]
    [[cameras]]      name, source, width, height, fps
    [twin]           seed, effect ("MODULE:FUNCTION"), [twin.effects] (bool per actuator effect),
                     faults (["KIND@T[:DURATION]", ...]: hardware/sim/faults.py),
                     description_error (bool, default true: the twin's arms are not their descriptions),
                     [twin.perception] (the simulated pose detector's settings: hardware/sim/perception.py)

load_rig(name_or_path) validates everything up front; every problem is a ConfigError naming the file, the
field and the fix. Ports and channels of simulated rigs are "twin": open_rig/serve_twin fill in the twin's
pty paths and virtual CAN channels. Driver names and their config dataclasses come from the device-kind
registry (hardware/registry.py), not from this file.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import typing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hardware.errors import ConfigError
from hardware.registry import device_kind
from hardware.rigs.toml_checks import as_array, as_table, check_type, need_key, typed_value, unknown_keys
from hardware.sim.actuators import EFFECT_NAMES, ActuatorParams
from hardware.sim.faults import parse_fault
from hardware.sim.perception import perception_params

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

RIG_DIR = Path(__file__).resolve().parent
DEFAULT_RIG = "sim-piper"
TWIN_PLACEHOLDER = "twin"  # port/channel value that the twin replaces with its own pty / virtual channel
LIMIT_FIELDS = ("q_min", "q_max", "v_max", "tau_max", "tau_rate_max", "kp_max", "kd_max")
DEVICE_KEYS = {"driver", "arm", "name", "limits", "twin", "next_checkpoint"}
DEVICE_TWIN_KEYS = {"motors", "start_q", "params"}
TOP_KEYS = {"rig", "leaders", "followers", "cameras", "twin", "pairs", "teleop"}
RIG_KEYS = {"name", "description", "simulated"}
CAMERA_KEYS = {"name": str, "source": str, "width": int, "height": int, "fps": float}
TWIN_KEYS = {"seed", "effect", "effects", "physics_hz", "control_hz", "scene", "task", "description_error",
             "faults", "perception"}


@dataclass
class DeviceSpec:
    """One leader or follower of a rig. config: its kind's config dataclass (None for a kind without one,
    e.g. driver "sim")."""

    name: str
    role: str  # "leader" | "follower"
    driver: str
    arm: str
    config: object | None
    limits_override: dict[str, np.ndarray] = field(default_factory=dict)
    next_checkpoint: str | None = None
    twin_motors: list[str] | None = None
    twin_start_q: list[float] | None = None
    twin_params: dict[str, object] = field(default_factory=dict)

    def limits(self):
        """The arm description's JointLimits with this rig's overrides applied."""
        from hardware.arms import load_arm

        base = load_arm(self.arm).limits
        kw = {f: getattr(base, f) for f in LIMIT_FIELDS}
        for k, v in self.limits_override.items():
            kw[k] = np.broadcast_to(v, (base.n,)).copy()
        from hardware.types import JointLimits

        try:
            return JointLimits(**kw)
        except ValueError as e:
            raise ConfigError(str(e), where=f"rig device {self.name} limits",
                              fix="check the override values") from None


@dataclass
class CameraSpec:
    name: str
    source: str  # "/dev/video0", an index, or "sim:<camera name>" for a twin camera
    width: int = 640
    height: int = 480
    fps: float = 30.0


# Hz: default rate of the twin's firmware laws, Python-side actuator effects and wire emulators. MuJoCo
# still integrates at physics_hz (>= 1 kHz) with the laws' damping and the friction slope implicit at every
# physics step; against 1 kHz laws on a 1-minute Piper replay the reported torque differs by 0.007-0.015 N*m
# (J1-J3) and 0.001-0.002 N*m (J4-J6) mean, below the current noise, and it halves the twin's Python cost
# (docs/twin.md "Speed"). Set control_hz = 1000 in a rig for 1 kHz laws.
CONTROL_HZ_DEFAULT = 500.0


@dataclass
class TwinSpec:
    """How the twin simulates the rig. effects: actuator effect name -> on/off; effect: undeclared-effect hook
    "MODULE:FUNCTION" (applied to every follower); physics_hz: MuJoCo step rate (>= 1000); control_hz: rate of
    the firmware laws, the Python-side effects and the emulators (<= physics_hz, which it must divide)."""

    seed: int = 0
    effect: str | None = None
    effects: dict[str, bool] = field(default_factory=dict)
    physics_hz: float = 1000.0
    control_hz: float = CONTROL_HZ_DEFAULT
    scene: str = "table"
    task: str | None = None  # a contact-rich task's objects in the scene (hardware/sim/tasks; `factr2 tasks`)
    # true: each twin arm simulates a true body that differs from its published description as a real unit
    # does (hardware/arms/true_body.py, per seed); false: the twin simulates the description exactly
    description_error: bool = True
    faults: tuple = ()  # hardware.sim.faults.FaultSpec to play, from ["KIND@T[:DURATION]", ...]
    # the simulated pose detector's settings ([twin.perception]: PerceptionParams fields, hardware/sim/
    # perception.py), over the defaults and the task's own; checked when the rig is loaded
    perception: dict = field(default_factory=dict)


@dataclass
class Rig:
    name: str
    path: Path
    description: str
    simulated: bool
    leaders: list[DeviceSpec]
    followers: list[DeviceSpec]
    cameras: list[CameraSpec]
    twin: TwinSpec
    pairs: list[tuple[str, str]]  # (leader name, follower name)
    # [teleop] table, raw: leader law gains, mapping, soft start (factr2_teleop.teleop.PairConfig.from_dict
    # validates it; the hardware layer does not know the teleop schema)
    teleop: dict = field(default_factory=dict)

    def device(self, name: str) -> DeviceSpec:
        for d in self.leaders + self.followers:
            if d.name == name:
                return d
        raise ConfigError(f"rig {self.name} has no device {name!r}", where=str(self.path),
                          fix=f"use one of {[d.name for d in self.leaders + self.followers]}")

    def with_endpoints(self, endpoints: dict[str, str]) -> Rig:
        """A copy whose devices reach a running twin: device name -> its pty / in-process port / virtual CAN
        channel (Twin.endpoints), written where each kind's config names it."""
        def fix(d: DeviceSpec) -> DeviceSpec:
            if d.name not in endpoints or d.config is None:
                return d
            config = device_kind(d.driver).with_endpoint(d.config, endpoints[d.name])
            return dataclasses.replace(d, config=config)
        return dataclasses.replace(self, leaders=[fix(d) for d in self.leaders],
                                   followers=[fix(d) for d in self.followers])


# -- loading ---------------------------------------------------------------------------------------------
def list_rigs() -> list[str]:
    """Names of the built-in rigs."""
    return sorted(p.stem for p in RIG_DIR.glob("*.toml"))


def rig_path(name_or_path: str | os.PathLike) -> Path:
    s = str(name_or_path)
    p = Path(s).expanduser()
    if p.suffix == ".toml" or os.sep in s:
        if not p.is_file():
            raise ConfigError(f"rig file {s} does not exist", where="--rig", fix="check the path")
        return p
    builtin = RIG_DIR / f"{s}.toml"
    if not builtin.is_file():
        raise ConfigError(f"unknown rig {s!r}", where="--rig",
                          fix=f"use one of {', '.join(list_rigs())} or a path to a .toml file")
    return builtin


def load_rig(name_or_path: str | os.PathLike = DEFAULT_RIG) -> Rig:
    """Parse and validate a rig (built-in name or path). ConfigError on any problem."""
    path = rig_path(name_or_path)
    try:
        doc = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"not valid TOML ({e})", where=str(path),
                          fix="fix the syntax at that line") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read ({e})", where=str(path), fix="check the file") from None
    return parse_rig(doc, path)


def parse_rig(doc: dict, path: Path) -> Rig:
    f = str(path)
    unknown_keys(doc, TOP_KEYS, f, "")
    head = as_table(doc.get("rig", {}), f, "rig")
    unknown_keys(head, RIG_KEYS, f, "rig")
    name = typed_value(head.get("name", path.stem), str, f, "rig.name")
    simulated = typed_value(head.get("simulated", False), bool, f, "rig.simulated")
    leaders = [_device(d, "leader", i, f, path)
               for i, d in enumerate(as_array(doc.get("leaders", []), f, "leaders"))]
    followers = [_device(d, "follower", i, f, path)
                 for i, d in enumerate(as_array(doc.get("followers", []), f, "followers"))]
    if not followers:
        raise ConfigError("no [[followers]] table", where=f, fix="add at least one follower")
    names = [d.name for d in leaders + followers]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ConfigError(f"device names repeat: {', '.join(sorted(dup))}", where=f,
                          fix="give every device its own name")
    cams = [_camera(c, i, f) for i, c in enumerate(as_array(doc.get("cameras", []), f, "cameras"))]
    twin = _twin(doc.get("twin", {}), f)
    if not simulated:
        for d in leaders + followers:
            if device_kind(d.driver).simulated_only:
                raise ConfigError(f"{d.role} {d.name} uses driver {d.driver!r} on a rig that is not "
                                  "simulated",
                                  where=f"{f}: {d.role}s.{d.name}.driver",
                                  fix="set [rig] simulated = true or use a driver with hardware behind it")
    pairs = _pairs(doc.get("pairs"), leaders, followers, f)
    desc = typed_value(head.get("description", ""), str, f, "rig.description")
    teleop = as_table(doc.get("teleop", {}), f, "teleop")
    return Rig(name=name, path=path, description=desc, simulated=simulated, leaders=leaders,
               followers=followers, cameras=cams, twin=twin, pairs=pairs, teleop=teleop)


def _device(d, role: str, i: int, f: str, path: Path) -> DeviceSpec:
    where = f"{role}s[{i}]"
    d = as_table(d, f, where)
    driver = typed_value(need_key(d, "driver", f, where, f"a {role} driver"), str, f, f"{where}.driver")
    kind = device_kind(driver, role, where=f"{f}: {where}.driver")
    arm = typed_value(need_key(d, "arm", f, where, "the arm description name, e.g. piper"), str, f,
                      f"{where}.arm")
    name = typed_value(d.get("name", role if i == 0 else f"{role}{i}"), str, f, f"{where}.name")
    cls = kind.config
    cfg_fields = {x.name: x for x in dataclasses.fields(cls)} if cls else {}
    unknown_keys(d, DEVICE_KEYS | set(cfg_fields), f, where)
    config = None
    if cls is not None:
        hints = typing.get_type_hints(cls)
        kw = {"arm": arm, "name": name}
        for k, v in d.items():
            if k in cfg_fields and k not in ("arm", "name"):
                kw[k] = check_type(v, hints[k], f, f"{where}.{k}")
        missing = [k for k, x in cfg_fields.items() if k not in kw and x.default is dataclasses.MISSING
                   and x.default_factory is dataclasses.MISSING]
        if missing:
            raise ConfigError(f"missing field {missing[0]!r}", where=f"{f}: {where}",
                              fix=f"add {missing[0]} = ... ({hints[missing[0]]}) to the table")
        config = cls(**kw)
    limits = {}
    for k, v in as_table(d.get("limits", {}), f, f"{where}.limits").items():
        if k not in LIMIT_FIELDS:
            raise ConfigError(f"unknown limit {k!r}", where=f"{f}: {where}.limits",
                              fix=f"use one of {', '.join(LIMIT_FIELDS)}")
        limits[k] = np.asarray(check_type(v, "float | list[float]", f, f"{where}.limits.{k}"), dtype=float)
    tw = as_table(d.get("twin", {}), f, f"{where}.twin")
    unknown_keys(tw, DEVICE_TWIN_KEYS, f, f"{where}.twin")
    motors = check_type(tw["motors"], "list[str]", f, f"{where}.twin.motors") if "motors" in tw else None
    start = check_type(tw["start_q"], "list[float]", f, f"{where}.twin.start_q") if "start_q" in tw else None
    params = as_table(tw.get("params", {}), f, f"{where}.twin.params")
    for k, v in params.items():
        if k not in ActuatorParams.ARRAY_FIELDS:
            raise ConfigError(f"unknown actuator parameter {k!r}", where=f"{f}: {where}.twin.params",
                              fix=f"use one of {', '.join(ActuatorParams.ARRAY_FIELDS)}")
        check_type(v, "float | list[float]", f, f"{where}.twin.params.{k}")
    ckpt = d.get("next_checkpoint")
    if ckpt is not None:
        ckpt = typed_value(ckpt, str, f, f"{where}.next_checkpoint")
        p = Path(ckpt).expanduser()
        ckpt = str(p if p.is_absolute() else (path.parent / p))
    return DeviceSpec(name=name, role=role, driver=driver, arm=arm, config=config, limits_override=limits,
                      next_checkpoint=ckpt, twin_motors=motors, twin_start_q=start, twin_params=params)


def _camera(c, i: int, f: str) -> CameraSpec:
    where = f"cameras[{i}]"
    c = as_table(c, f, where)
    unknown_keys(c, set(CAMERA_KEYS), f, where)
    kw = {k: check_type(v, CAMERA_KEYS[k].__name__, f, f"{where}.{k}") for k, v in c.items()}
    for k in ("name", "source"):
        need_key(c, k, f, where, "a string")
    return CameraSpec(**kw)


def _twin(t, f: str) -> TwinSpec:
    t = as_table(t, f, "twin")
    unknown_keys(t, TWIN_KEYS, f, "twin")
    effects = as_table(t.get("effects", {}), f, "twin.effects")
    for k, v in effects.items():
        if k not in EFFECT_NAMES:
            raise ConfigError(f"unknown effect {k!r}", where=f"{f}: twin.effects",
                              fix=f"use one of {', '.join(EFFECT_NAMES)}")
        typed_value(v, bool, f, f"twin.effects.{k}")
    hz = float(check_type(t.get("physics_hz", 1000.0), "float", f, "twin.physics_hz"))
    if hz < 1000.0:
        raise ConfigError(f"physics_hz {hz:g} is below 1000", where=f"{f}: twin.physics_hz",
                          fix="use 1000 or more (control_hz sets the firmware laws' rate)")
    chz = float(check_type(t.get("control_hz", CONTROL_HZ_DEFAULT), "float", f, "twin.control_hz"))
    k = hz / chz if chz > 0 else 0.0
    if chz <= 0 or chz > hz or abs(k - round(k)) > 1e-9:
        raise ConfigError(f"control_hz {chz:g} does not divide physics_hz {hz:g}",
                          where=f"{f}: twin.control_hz",
                          fix="use physics_hz / k for a whole k >= 1, e.g. 1000 or 500")
    eff = t.get("effect")
    perception = as_table(t.get("perception", {}), f, "twin.perception")
    perception_params(perception, where=f"{f}: twin.perception")  # ConfigError (one line) when bad
    return TwinSpec(perception=dict(perception), seed=typed_value(t.get("seed", 0), int, f, "twin.seed"),
                    effect=None if eff is None else typed_value(eff, str, f, "twin.effect"),
                    effects=dict(effects), physics_hz=hz, control_hz=chz,
                    scene=typed_value(t.get("scene", "table"), str, f, "twin.scene"),
                    task=typed_value(t["task"], str, f, "twin.task") if "task" in t else None,
                    description_error=typed_value(t.get("description_error", True), bool, f,
                                             "twin.description_error"),
                    faults=tuple(parse_fault(x, where=f"{f}: twin.faults[{i}]") for i, x in
                                 enumerate(check_type(t.get("faults", []), "list[str]", f, "twin.faults"))))


def _pairs(raw, leaders, followers, f: str) -> list[tuple[str, str]]:
    if raw is None:
        return [(a.name, b.name) for a, b in zip(leaders, followers)]
    out = []
    names_l, names_f = {d.name for d in leaders}, {d.name for d in followers}
    for i, p in enumerate(as_array(raw, f, "pairs")):
        p = as_table(p, f, f"pairs[{i}]")
        unknown_keys(p, {"leader", "follower"}, f, f"pairs[{i}]")
        a, b = p.get("leader"), p.get("follower")
        if a not in names_l or b not in names_f:
            raise ConfigError(f"pair {a!r} -> {b!r} names an unknown device", where=f"{f}: pairs[{i}]",
                              fix=f"leaders: {', '.join(sorted(names_l))}; "
                                  f"followers: {', '.join(sorted(names_f))}")
        out.append((a, b))
    return out
