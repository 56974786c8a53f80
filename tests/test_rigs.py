"""Rig files: built-ins load and build driver configs; every malformed file is a one-line ConfigError that
names the file, the field and the fix."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.damiao.config import DamiaoFollowerConfig
from hardware.dynamixel.config import DynamixelLeaderConfig
from hardware.errors import ConfigError
from hardware.piper.config import PiperFollowerConfig
from hardware.rigs import DEFAULT_RIG, list_rigs, load_rig

GOOD = """
[rig]
name = "mine"
simulated = true

[[leaders]]
driver = "dynamixel"
arm = "gello_piper"
port = "twin"
ids = [1, 2, 3, 4, 5, 6]
signs = [1, 1, 1, 1, 1, -1]
offsets_rad = [0, 0, 0, 0, 0, 0]

[[followers]]
driver = "piper"
arm = "piper"
channel = "twin"
next_checkpoint = "ckpt/next.safetensors"
[followers.limits]
v_max = 1.0
[followers.twin]
start_q = [0.0, 0.5, -0.5, 0.0, 0.0, 0.0]
[followers.twin.params]
stribeck = 0.3

[twin]
seed = 7
effect = "mypkg:fn"
[twin.effects]
ripple = false
"""


def test_builtin_rigs_load_and_build_configs():
    names = list_rigs()
    for n in ("sim-piper", "sim-yam", "sim-panda", "sim-bimanual-piper", "piper", "yam", "bimanual-piper"):
        assert n in names
    assert DEFAULT_RIG == "sim-piper"
    for n in names:
        rig = load_rig(n)
        assert rig.followers and rig.pairs
        for d in rig.leaders:
            assert isinstance(d.config, DynamixelLeaderConfig)
        for d in rig.followers:
            assert d.driver == "sim" or isinstance(d.config, PiperFollowerConfig | DamiaoFollowerConfig)
        assert rig.simulated == n.startswith("sim-")
    real = load_rig("piper").followers[0].config
    assert real.channel == "can0" and real.interface == "socketcan"
    assert load_rig("sim-bimanual-piper").pairs == [("left_leader", "left_follower"),
                                                    ("right_leader", "right_follower")]


def test_custom_rig_fields_and_limits(tmp_path):
    p = tmp_path / "mine.toml"
    p.write_text(GOOD)
    rig = load_rig(p)
    f = rig.followers[0]
    assert f.next_checkpoint == str(tmp_path / "ckpt/next.safetensors")
    assert f.twin_start_q[1] == 0.5 and f.twin_params == {"stribeck": 0.3}
    assert rig.twin.seed == 7 and rig.twin.effect == "mypkg:fn" and rig.twin.effects == {"ripple": False}
    assert np.all(f.limits().v_max == 1.0)
    assert rig.leaders[0].config.signs[-1] == -1
    moved = rig.with_endpoints({"leader": "/dev/pts/9", "follower": "vcan-x"})
    assert moved.leaders[0].config.port == "/dev/pts/9"
    assert moved.followers[0].config.channel == "vcan-x" and moved.followers[0].config.interface == "virtual"


@pytest.mark.parametrize("old,new,needle", [
    ('arm = "piper"\nchannel', 'arm = "piper"\ncolour = "red"\nchannel', "unknown key 'colour'"),
    ('ids = [1, 2, 3, 4, 5, 6]', 'ids = "1-6"', "leaders[0].ids: expected list[int]"),
    ('port = "twin"\n', '', "missing field 'port'"),
    ('driver = "piper"', 'driver = "kuka"', "unknown driver 'kuka'"),
    ('v_max = 1.0', 'v_fast = 1.0', "unknown limit 'v_fast'"),
    ('stribeck = 0.3', 'stiction = 0.3', "unknown actuator parameter 'stiction'"),
    ('ripple = false', 'ripple = "no"', "twin.effects.ripple: expected bool"),
    ('ripple = false', 'wobble = true', "unknown effect 'wobble'"),
    ('seed = 7', 'seed = 7.5', "twin.seed: expected int"),
    ('[rig]', '[rigg]', "unknown key 'rigg'"),
    ('name = "mine"', 'name = ', "not valid TOML"),
])
def test_validation_errors_name_file_field_and_fix(tmp_path, old, new, needle):
    p = tmp_path / "bad.toml"
    assert old in GOOD
    p.write_text(GOOD.replace(old, new, 1))
    with pytest.raises(ConfigError) as e:
        load_rig(p)
    msg = str(e.value)
    assert needle in msg and str(p) in msg and "fix:" in msg and "\n" not in msg


def test_unknown_rig_name_and_missing_file():
    with pytest.raises(ConfigError, match="unknown rig 'nope'.*sim-piper"):
        load_rig("nope")
    with pytest.raises(ConfigError, match="does not exist"):
        load_rig("/no/such/rig.toml")


def test_sim_driver_needs_simulated_rig(tmp_path):
    p = tmp_path / "r.toml"
    p.write_text('[rig]\nsimulated = false\n[[followers]]\ndriver = "sim"\narm = "panda"\n')
    with pytest.raises(ConfigError, match="driver 'sim' on a rig that is not simulated"):
        load_rig(p)


def test_every_device_kind_resolves_and_serves_every_builtin_rig():
    """Each device folder declares its kind once; every name it declares imports and is callable."""
    import importlib

    from hardware.registry import KIND_MODULES, device_kind, device_kinds

    kinds = device_kinds()
    assert [k.driver for k in kinds] == ["dynamixel", "piper", "damiao", "sim"] and len(KIND_MODULES) == 4
    for k in kinds:
        for ref in (k.driver_ref, k.emulator_ref, k.probe_ref, k.bare_probe_ref):
            if ref is not None:
                mod, _, attr = ref.partition(":")
                assert callable(getattr(importlib.import_module(mod), attr)), ref
        assert (k.wire is None) == (k.emulator_ref is None) == k.simulated_only
    assert [k.driver for k in device_kinds("leader")] == ["dynamixel"]
    for n in list_rigs():
        for d in load_rig(n).leaders + load_rig(n).followers:
            k = device_kind(d.driver, d.role)
            assert d.config is None if k.config is None else isinstance(d.config, k.config)
            drive = k.twin_drive(d.config)
            assert isinstance(drive.gripper_motor, str) and drive.gripper_motor
    with pytest.raises(ConfigError, match=r"unknown driver 'piper' for a leader.*\['dynamixel'\]"):
        device_kind("piper", "leader")
