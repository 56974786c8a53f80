"""bench/faults.py, the fault campaign (SIMULATED): one seeded trial, its JSON row, and a resumed run that
does not run a finished trial again (a line cut by a kill is run again)."""

from __future__ import annotations

import json

from bench import faults as campaign


def test_campaign_row_and_resume(tmp_path, capsys):
    out = tmp_path / "c.json"
    args = ["--seed", "1", "--per-kind", "2", "--kinds", "spike_leader", "--activities", "teleop", "--json",
            str(out)]
    assert campaign.main(args) == 0
    row = json.loads(out.read_text())["payload"]["kinds"]["spike_leader"]
    assert row["injected"] == row["trials"] == row["trials_safe"] == 2
    assert row["violations"] == 0 and row["samples_lost"] == 0 and row["errors"] == 0
    assert row["recoveries"] == row["recovery_owed"] == 2
    journal = out.with_name(out.name + ".trials.jsonl")
    lines = journal.read_text().splitlines()
    assert len(lines) == 2
    journal.write_text(lines[0] + "\n" + lines[1][: len(lines[1]) // 2])  # killed while writing the second
    capsys.readouterr()
    assert campaign.main(args) == 0
    assert "2 trials, 1 done before, 1 to run" in capsys.readouterr().err
    assert json.loads(out.read_text())["payload"]["kinds"]["spike_leader"]["trials"] == 2


def test_bad_activity_is_one_line(capsys):
    assert campaign.main(["--activities", "fly", "--json", "/dev/null"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown activity fly" in err
