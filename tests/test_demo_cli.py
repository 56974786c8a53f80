"""`factr2 demo` end to end on the twin (SIMULATED, lockstep, short) and its input errors."""

from __future__ import annotations

import json

import pytest

from factr2_teleop.cli import main

KEYS = ("loop_hz", "period_p99_ms", "overruns", "feedback_corr", "feedback_lag_ms", "tau_ext_l1_contact",
        "tau_ext_l1_free", "max_command_violation", "mode")


def test_demo_headless_writes_the_metrics(tmp_path):
    out = tmp_path / "demo.json"
    rc = main(["demo", "--headless", "--seconds", "6", "--clock", "lockstep", "--rate", "250",
               "--mode", "ground_truth", "--json", str(out), "--record", str(tmp_path / "rec")])
    assert rc == 0
    assert len(list((tmp_path / "rec").glob("demo-sim-piper-*.mcap"))) == 1
    d = json.loads(out.read_text())
    assert all(k in d for k in KEYS)
    assert d["mode"] == "ground_truth" and d["simulated"] is True
    assert d["max_command_violation"] == 0
    assert d["ticks"] >= 6 * 250 * 0.95 and abs(d["loop_hz"] - 250) < 1  # lockstep: exact rate
    assert d["tau_ext_l1_contact"] > d["tau_ext_l1_free"]  # the task really touches the table
    assert d["feedback_corr"] > 0.8


def test_demo_auto_without_next_says_which_mode_ran(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("FACTR2_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "demo.json"
    rc = main(["demo", "--headless", "--seconds", "1", "--clock", "lockstep", "--rate", "250",
               "--no-calibrate", "--json", str(out)])
    assert rc == 0
    d = json.loads(out.read_text())
    assert d["mode"] == "dob" and "no cached NEXT" in d["next_unavailable"]
    assert "feedback mode dob" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["--seconds", "0"], ["--rate", "-5"], ["--rig", "piper"],
                                  ["--mode", "next", "--checkpoint", "/nonexistent/next.json"]])
def test_demo_bad_input_is_one_line_exit_2(argv, capsys):
    assert main(["demo", "--headless", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
