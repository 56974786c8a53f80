"""`factr2 tasks` and `factr2 collect` bad input: one line, exit 2, nothing written (SIMULATED rigs)."""

from factr2_teleop.cli import main


def test_tasks_lists_every_task_with_stages(capsys):
    assert main(["tasks"]) == 0
    out = capsys.readouterr().out
    for name, stages in (("peg-insert", "grasp -> align -> insert"), ("wipe", "reach -> contact -> coverage"),
                         ("press-fit", "grasp -> align -> seat")):
        assert name in out and stages in out


def _collect(tmp_path, *extra):
    return main(["collect", "--episodes", "1", "--out", str(tmp_path), "--mode", "dob", *extra])


def _one_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "error" in err[0], err
    return err[0]


def test_unknown_task(tmp_path, capsys):
    assert _collect(tmp_path, "--task", "juggle") == 2
    line = _one_line(capsys)
    assert "unknown task" in line and not any(tmp_path.iterdir())
    names = "use one of cap-screw, peg-insert, press-fit, tight-insert, wipe ("
    assert names in line and "['" not in line  # names, not a list repr


def test_task_on_a_rig_that_cannot_hold_it(tmp_path, capsys):
    assert _collect(tmp_path, "--task", "peg-insert", "--rig", "sim-panda") == 2
    line = _one_line(capsys)
    assert "does not fit" in line and "follower is one of piper (" in line and not any(tmp_path.iterdir())
    assert _collect(tmp_path, "--task", "wipe", "--rig", "piper") == 2  # real hardware
    assert "real hardware" in _one_line(capsys) and not any(tmp_path.iterdir())


def test_existing_output_is_never_overwritten(tmp_path, capsys):
    f = tmp_path / "wipe-sim-piper-seed3.mcap"
    f.write_bytes(b"keep")
    assert _collect(tmp_path, "--task", "wipe", "--seed", "3") == 2
    assert "already exists" in _one_line(capsys) and f.read_bytes() == b"keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == [f.name]
