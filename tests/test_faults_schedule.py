"""The fault schedule (hardware/sim/faults.py): parsing KIND@T[:DURATION], one-line errors, seeded draws."""

from __future__ import annotations

import pytest

from hardware.errors import ConfigError
from hardware.sim.faults import KINDS, FaultSpec, parse_fault, random_schedule


def test_parse_with_and_without_duration():
    assert parse_fault("can_busoff@2.5:0.3") == FaultSpec("can_busoff", 2.5, 0.3)
    assert parse_fault("spike_leader@1") == FaultSpec("spike_leader", 1.0, KINDS["spike_leader"][1])


@pytest.mark.parametrize("bad", ["busoff@1", "can_busoff", "can_busoff@x", "can_busoff@1:-2", "can_loss@nan"])
def test_bad_fault_is_one_line_config_error(bad):
    with pytest.raises(ConfigError) as e:
        parse_fault(bad)
    assert "\n" not in str(e.value) and "KIND@T" in str(e.value)


def test_random_schedule_is_seeded_sorted_and_apart():
    kinds = ["can_loss", "dxl_unplug", "spike_follower"]
    a = random_schedule(3, kinds, 6, 1.0, 30.0)
    assert a == random_schedule(3, kinds, 6, 1.0, 30.0) and a != random_schedule(4, kinds, 6, 1.0, 30.0)
    assert sorted(s.kind for s in a) == sorted(kinds * 2)
    for p, q in zip(a, a[1:], strict=False):
        assert q.t_s >= p.t_s + p.duration_s + 1.0 - 1e-9
    assert a[-1].t_s + a[-1].duration_s <= 30.0


def _rig_with(tmp_path, line: str):
    from hardware.rigs.rig import load_rig, rig_path

    text = rig_path("sim-piper").read_text().replace("[twin]\n", f"[twin]\n{line}\n", 1)
    (tmp_path / "r.toml").write_text(text)
    return load_rig(tmp_path / "r.toml")


def test_rig_file_schedules_faults_and_names_a_bad_one(tmp_path):
    rig = _rig_with(tmp_path, 'faults = ["can_busoff@1.0:0.2", "spike_leader@2"]')
    assert [f.text() for f in rig.twin.faults] == ["can_busoff@1:0.2", "spike_leader@2:0"]
    with pytest.raises(ConfigError, match=r"twin.faults\[0\].*unknown kind 'nope'"):
        _rig_with(tmp_path, 'faults = ["nope@1"]')


def test_the_twin_plays_the_rig_files_faults_and_logs_them(tmp_path):
    from hardware.clock import LockstepClock
    from hardware.sim.twin import Twin

    rig = _rig_with(tmp_path, 'faults = ["can_busoff@0.01:0.02"]')
    with Twin(rig, dynamixel_transport="inprocess") as twin:
        twin.attach(LockstepClock())
        emu = twin.devices["follower"].emulator
        twin.advance(twin.rig_time() + 0.02)
        assert emu.silent
        twin.advance(twin.rig_time() + 0.02)
        assert not emu.silent
        assert [(e["kind"], e["event"]) for e in twin.faults.log] == [("can_busoff", "start"),
                                                                      ("can_busoff", "end")]


@pytest.mark.parametrize("cmd", [["teleop", "--rig", "sim-piper"],
                                 ["collect", "--task", "peg-insert", "--out", "unused"],
                                 ["rollout", "--policy", "unused", "--task", "peg-insert"]])
def test_every_twin_command_takes_twin_fault_and_a_bad_one_is_one_line(cmd, capsys):
    from factr2_teleop.cli import main

    assert main([*cmd, "--twin-fault", "busoff@1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--twin-fault: bad fault 'busoff@1': unknown kind" in err
