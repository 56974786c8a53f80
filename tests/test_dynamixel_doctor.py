"""`factr2 doctor` against the emulator: servo table, wrong ids, wrong baud, missing port, CAN hook."""

from __future__ import annotations

from factr2_teleop.cli import main
from factr2_teleop.commands.doctor import parse_ids
from hardware import doctor as dr
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.dynamixel_probe import probe_dynamixel
from hardware.serial_ports import latency_timer_advice, list_serial_ports
from hardware.sim.motors import IdealMotorBank


def test_probe_reports_servos_and_round_trip():
    bank = IdealMotorBank(3)
    bank.q[:] = [0.1, 0.2, 0.3]
    with DynamixelEmulator(
        bank, [1, 2, 3], ["XL330-M288", "XL330-M288", "XM430-W350"], return_delay=0
    ) as emu:
        rep = probe_dynamixel(emu.port_path, 4_000_000, [1, 2, 3], loop_hz=1.0, rounds=10)
        assert [s.model for s in rep.servos] == ["XL330-M288", "XL330-M288", "XM430-W350"]
        assert all(s.return_delay_us == 0 and s.temperature_c == 30 and not s.torque_on for s in rep.servos)
        assert rep.round_trip_s > 0
        assert not [f for f in rep.findings if f.level == "error"]
        assert any(f.level == "ok" and "Hz" in f.message for f in rep.findings)
        assert any(s.path == emu.port_path for s in list_serial_ports([emu.port_path]))


def test_wrong_ids_and_wrong_baud_are_named():
    bank = IdealMotorBank(2)
    with DynamixelEmulator(bank, [1, 2], baud=57600) as emu:
        rep = probe_dynamixel(emu.port_path, 57600, [1, 5], rounds=5)
        err = [f for f in rep.findings if f.level == "error"]
        assert len(err) == 1 and "[5]" in err[0].message and "[1, 2]" in err[0].message
        rep = probe_dynamixel(emu.port_path, 4_000_000, [1, 2], rounds=5)
        err = [f for f in rep.findings if f.level == "error"]
        assert len(err) == 1 and "57600" in err[0].message and "baud = 57600" in err[0].fix


def test_cli_exit_codes(capsys):
    assert main(["doctor", "--port", "/dev/ttyUSB_missing", "--ids", "1-2"]) == 1
    out = capsys.readouterr().out
    assert "ERROR /dev/ttyUSB_missing: serial port /dev/ttyUSB_missing does not exist" in out
    assert main(["doctor", "--ids", "1-x", "--port", "/dev/null"]) == 2  # bad input: one line, exit 2
    assert "--ids" in capsys.readouterr().err
    with DynamixelEmulator(IdealMotorBank(2), [1, 2], return_delay=0) as emu:
        assert main(["doctor", "--port", emu.port_path, "--ids", "1-2"]) == 0
        out = capsys.readouterr().out
        assert "XL330-M288" in out and "doctor: no errors" in out


def test_can_hook_and_helpers(tmp_path):
    calls = []

    def probe(iface):
        calls.append(iface)
        return [dr.Finding("ok", iface, "answered")]

    dr.register_can_check("test-probe", probe)
    try:
        assert any(f.message == "answered" for f in dr.run_can_checks("vcan9")) and calls == ["vcan9"]
    finally:
        dr._CAN_CHECKS.pop("test-probe")
    for name, typ in (("can0", "280"), ("eth0", "1")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "type").write_text(typ)
        (tmp_path / name / "operstate").write_text("up")
        (tmp_path / name / "flags").write_text("0x1")
    assert [c.name for c in dr.check_can_interfaces(str(tmp_path))] == ["can0"]
    assert parse_ids("1-3,9") == [1, 2, 3, 9]
    assert latency_timer_advice("/dev/ttyUSB0", 16) and "echo 1" in latency_timer_advice("/dev/ttyUSB0", 16)
    assert latency_timer_advice("/dev/ttyUSB0", 1) is None


def test_rig_checks_probe_each_device_with_its_kind_on_a_served_twin():
    """`factr2 doctor --rig` goes through the device-kind registry: a twin's Dynamixel pty and its Piper on
    a virtual CAN channel (this process), each probed with the rig's own config (SIMULATED devices)."""
    from hardware.connect import serve_twin
    from hardware.rigs import load_rig

    rig = load_rig("sim-piper")
    checks, notes = dr.rig_checks(rig, loop_hz=1.0)
    assert checks == [] and len(notes) == 2  # "twin" endpoints: nothing to probe without a twin
    with serve_twin(rig) as twin:
        checks, notes = dr.rig_checks(rig.with_endpoints(twin.twin.endpoints), loop_hz=1.0)
    assert notes == [] and [c.title.split()[0] for c in checks] == ["dynamixel", "CAN"]
    assert not any(c.failed for c in checks), [f.line() for c in checks for f in c.findings]
    assert sum("XL330-M288" in line for line in checks[0].details) == 7  # 6 joints + trigger
    assert any("AgileX Piper" in f.message or "firmware" in f.message for f in checks[1].findings)
