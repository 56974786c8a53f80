"""Logs' joint names against an arm's (calibration/joint_map.py) and through `factr2 diagnose`: a common
suffix or no names are mapped by order with one line; a real mismatch is one line whose fix works (the test
runs the suggested flag). Logs: RNEA of the Piper description plus noise (SIMULATED)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from calibration.joint_map import JointMismatch, match_joints, parse_joint_map
from factr2_teleop.cli import main

UR = ["base", "shoulder", "elbow", "wrist1", "wrist2", "wrist3"]


def test_suffix_prefix_and_no_names_map_by_order_with_one_line():
    order, note = match_joints([n + "_joint" for n in UR], UR, arm="ur5")
    assert order == list(range(6)) and "common prefix/suffix" in note and "\n" not in note
    assert match_joints(["j1", "j2"], ["joint1", "joint2"])[0] == [0, 1]
    order, note = match_joints([], UR, arm="ur5", n_columns=6)
    assert order == list(range(6)) and "name no joints" in note
    assert match_joints(UR, UR) == (list(range(6)), "")


@pytest.mark.parametrize("log", [UR[::-1], [n + "_joint" for n in UR[::-1]], list("abcdef")])
def test_a_mismatch_suggests_a_joint_map_that_works(log):
    with pytest.raises(JointMismatch) as e:
        match_joints(log, UR, arm="ur5")
    fix = re.search(r"--joint-map (\S+)", e.value.fix).group(1)
    order, _ = match_joints(log, UR, fix, arm="ur5")
    if log[0].startswith("wrist3"):  # reversed names: the map reorders them back
        assert order == list(range(6))[::-1]
    else:
        assert sorted(order) == list(range(6))


def test_another_count_is_refused_and_points_at_the_arm():
    with pytest.raises(JointMismatch) as e:
        match_joints(UR[:5], UR, arm="ur5")
    assert "--arm" in e.value.fix
    with pytest.raises(JointMismatch):
        match_joints([], UR, arm="ur5", n_columns=5)
    with pytest.raises(ValueError):
        parse_joint_map("a=b,a=c")


def _log(path, names, order=None):
    from hardware.arms import load_arm

    model = load_arm("piper").pinocchio_model()
    import pinocchio as pin

    data = model.createData()
    t = np.arange(0, 8.0, 0.01)
    q = 0.3 * np.sin(np.outer(t, [0.7, 0.9, 1.1, 1.3, 1.5, 1.7])) + np.array([0, 1.0, -1.0, 0, 0, 0])
    qd = np.gradient(q, t, axis=0)
    qdd = np.gradient(qd, t, axis=0)
    tau = np.stack([pin.rnea(model, data, q[i], qd[i], qdd[i]) for i in range(len(t))])
    tau += 0.01 * np.random.default_rng(0).standard_normal(tau.shape)
    o = list(range(6)) if order is None else order
    kw = {} if names is None else {"joint_names": np.array(names)}
    np.savez(path, t=t, q=q[:, o], qd=qd[:, o], q_cmd=q[:, o], tau_m=tau[:, o], **kw)
    return str(path)


def _diagnose(tmp_path, log, *extra):
    out = tmp_path / "d"
    return main(["diagnose", log, "--arm", "piper", "--out", str(out), "--no-plots", "--max-effects", "0",
                 *extra]), out


def test_cli_accepts_suffixed_names_with_one_line(tmp_path, capsys):
    names = [f"joint{k}_joint" for k in range(1, 7)]
    rc, out = _diagnose(tmp_path, _log(tmp_path / "suffixed.npz", names))
    assert rc == 0
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("note:")]
    assert len(lines) == 1 and "mapped by order" in lines[0]
    assert json.loads((out / "report.json").read_text())["joints"] == [f"joint{k}" for k in range(1, 7)]


def test_cli_refuses_a_permutation_and_its_fix_works(tmp_path, capsys):
    order = [1, 0, 2, 3, 4, 5]
    names = [f"joint{k + 1}" for k in order]
    log = _log(tmp_path / "swapped.npz", names, order)
    rc, _ = _diagnose(tmp_path, log)
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "another order" in err
    fix = re.search(r"--joint-map (\S+)", err).group(1)
    rc, out = _diagnose(tmp_path, log, "--joint-map", fix)
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    base = tmp_path / "base"
    assert main(["diagnose", _log(tmp_path / "plain.npz", [f"joint{k}" for k in range(1, 7)]), "--arm",
                 "piper", "--out", str(base), "--no-plots", "--max-effects", "0"]) == 0
    plain = json.loads((base / "report.json").read_text())
    # reordered back: the same per-joint fit as the log written in the arm's order
    assert np.allclose(rep["after"]["heldout_l1"], plain["after"]["heldout_l1"], rtol=1e-6)


def test_calibrate_from_logs_maps_suffixed_names_and_its_refusal_fix_works(tmp_path, capsys):
    """`factr2 calibrate --from-logs`: the issue's case (a log whose names differ from the arm's by a
    suffix) trains with one line; a permuted log is refused with a --joint-map that then trains."""
    suffixed = _log(tmp_path / "suffixed.npz", [f"joint{k}_joint" for k in range(1, 7)])
    tiny = ["--arm", "piper", "--arch", "mlp", "--history", "10", "--hidden", "16", "--max-epochs", "1",
            "--max-seconds", "5", "--prior", "description", "--no-plots"]
    assert main(["calibrate", "--from-logs", suffixed, "--out", str(tmp_path / "c1"), *tiny]) == 0
    err = capsys.readouterr().err
    assert sum("mapped by order" in x for x in err.splitlines()) == 1
    order = [1, 0, 2, 3, 4, 5]
    swapped = _log(tmp_path / "swapped.npz", [f"joint{k + 1}" for k in order], order)
    assert main(["calibrate", "--from-logs", swapped, "--out", str(tmp_path / "c2"), *tiny]) == 2
    err = capsys.readouterr().err
    errors = [x for x in err.splitlines() if "error" in x]
    assert len(errors) == 1 and "another order" in errors[0]
    fix = re.search(r"--joint-map (\S+)", err).group(1)
    assert main(["calibrate", "--from-logs", swapped, "--out", str(tmp_path / "c2"), *tiny,
                 "--joint-map", fix]) == 0
    rep = json.loads((tmp_path / "c2" / "report.json").read_text())
    assert rep["joint_names"] == [f"joint{k}" for k in range(1, 7)]
