"""`factr2 diagnose` end to end: report files, one-line errors, the NEXT path, and the real UR5 logs (skipped
when /work/shared/data/ur5_kufieta2014 is absent). Synthetic logs are simulated
(calibration.diagnosis.synthetic)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calibration.diagnosis.synthetic import analytic_arm
from factr2_teleop.cli import main

UR5 = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ur5_kufieta2014"


def _write_runs(tmp_path, effect, joint, n=3, seconds=30.0, **params):
    paths = []
    for s in range(n):
        g = analytic_arm(effect, joint, seconds, seed=s, **params)
        p = tmp_path / f"run{s}.npz"
        np.savez(p, t=g.t, q=g.q, qd=g.qd, q_cmd=g.q, tau_m=g.tau)
        paths.append(str(p))
    return paths


def test_cli_writes_report_with_steps_and_plots(tmp_path):
    runs = _write_runs(tmp_path, "position_periodic", 1, period_rad=0.3)
    out = tmp_path / "diag"
    assert main(["diagnose", *runs, "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["steps"][0]["added"] is None
    added = rep["steps"][1]["added"]
    assert (added["effect"], added["joint"]) == ("position_periodic", 1)
    assert added["params"]["period_rad"] == pytest.approx(0.3, rel=0.05)
    assert rep["after"]["heldout_l1"][1] <= 0.5 * rep["before"]["heldout_l1"][1]
    assert len(rep["steps"][1]["heldout_l1"]) == 3 and len(rep["joints"]) == 3
    assert rep["effects"][0]["effect"] == "position_periodic"
    md = (out / "report.md").read_text()
    assert "step01_position_periodic_j1.png" in md and (out / "step01_position_periodic_j1.png").exists()


def test_cli_no_effect_says_the_model_explains_the_data(tmp_path):
    runs = _write_runs(tmp_path, None, 0)
    out = tmp_path / "diag"
    assert main(["diagnose", *runs, "--out", str(out), "--no-plots"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["effects"] == [] and "explains the data" in rep["verdict"]


def test_cli_declared_report_is_fitted_not_found_again(tmp_path, capsys):
    runs = _write_runs(tmp_path, "coulomb_friction", 1, fc=0.8)
    first = tmp_path / "first"
    assert main(["diagnose", *runs, "--out", str(first), "--no-plots"]) == 0
    found = json.loads((first / "report.json").read_text())["effects"]
    assert ("coulomb_friction", 1) in [(e["effect"], e["joint"]) for e in found]
    second = tmp_path / "second"
    assert main(["diagnose", *runs, "--declared", str(first / "report.json"), "--out", str(second),
                 "--no-plots"]) == 0
    rep = json.loads((second / "report.json").read_text())
    assert [(e["effect"], e["joint"]) for e in rep["declared"]] == [(e["effect"], e["joint"]) for e in found]
    assert "explains the data" in rep["verdict"]
    capsys.readouterr()
    (tmp_path / "junk.json").write_text("{\"effects\": [{\"effect\": \"warp_drive\", \"joint\": 0}]}")
    junk = str(tmp_path / "junk.json")
    assert main(["diagnose", *runs, "--declared", junk, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "junk.json" in err[0], err


def test_cli_bad_inputs_are_one_line_errors(tmp_path, capsys):
    assert main(["diagnose", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "o")]) == 2
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file at all")
    assert main(["diagnose", str(bad), "--out", str(tmp_path / "o")]) == 2
    np.savez(tmp_path / "cur.npz", t=np.arange(100) * 0.01, q=np.zeros((100, 6)), qd=np.zeros((100, 6)),
             q_cmd=np.zeros((100, 6)), current=np.zeros((100, 6)))
    assert main(["diagnose", str(tmp_path / "cur.npz"), "--arm", "pinocchio-sample",
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("factr2 diagnose: error:") for line in err)
    assert "--kt" in err[-1]


def test_cli_next_checkpoint_runs_the_loop_on_its_residual(tmp_path):
    """Mechanics of --model: a real (tiny, briefly trained) NEXT checkpoint is loaded, predicted on the
    resampled logs, and the loop adds grey-box terms only where they lower held-out error."""
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from calibration.next.checkpoint import NextCheckpoint, save_checkpoint
    from calibration.next.data import Segment as NSeg
    from calibration.next.data import build_windows
    from calibration.next.train import TrainConfig, train

    base = [analytic_arm(None, 0, 10.0, seed=s) for s in range(2)]
    data = build_windows([NSeg(t=g.t, q=g.q, qd=g.qd, q_cmd=g.q, tau=g.tau, rate_hz=100.0) for g in base],
                         history=10, inputs="q,qd,dq")
    res = train(data, TrainConfig(arch="mlp", history=10, head_hidden=32, max_epochs=2, threads=1,
                                  device="cpu", samples_per_epoch=1024), progress_bar=False)
    ck = NextCheckpoint(model=res.model, normalizer=data.normalizer, arm="", joint_names=["j0", "j1", "j2"],
                        units="N*m", inputs="q,qd,dq", rate_hz=100.0, x_min=data.x_min, x_max=data.x_max)
    path = save_checkpoint(ck, tmp_path / "next")
    runs = _write_runs(tmp_path, "drift", 2, n=3, seconds=15.0, rate_per_min=20.0)
    out = tmp_path / "diag"
    assert main(["diagnose", *runs, "--model", str(path), "--out", str(out), "--no-plots",
                 "--max-effects", "2"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert "NEXT" in rep["basis"]
    assert rep["after"]["heldout_l1_mean"] <= rep["before"]["heldout_l1_mean"]
    assert main(["diagnose", *runs, "--model", str(tmp_path / "nope"), "--out", str(out)]) == 2


def test_next_basis_residual_traced_to_what_it_cannot_see():
    """A predictor that knows the arm but not time (a stand-in for a well-trained NEXT: the noise-free
    simulated rigid torque) misses a drift over the run; the loop must trace it to drift on joint 2."""
    from calibration.diagnosis.loop import diagnose
    from calibration.diagnosis.next_loop import NextBasis
    from calibration.diagnosis.synthetic import analytic_torque

    runs = [analytic_arm("drift", 2, 30.0, seed=s, name=f"r{s}", rate_per_min=1.0) for s in range(3)]
    preds = {id(r): analytic_torque(r.q, r.qdd) for r in runs}
    dg = diagnose(NextBasis(3, preds, "stand-in predictor"), runs[:2], runs[2:])
    assert [(e.family, e.joint) for e in dg.model.effects] == [("drift", 2)]
    assert dg.steps[-1].heldout_l1[2] <= 0.5 * dg.steps[0].heldout_l1[2]


@pytest.mark.skipif(not (UR5 / "Movement_No7_Acc_slow_Verify_Model_short.npz").exists(),
                    reason="UR5 logs not present (shared/data/ur5_kufieta2014)")
def test_real_ur5_friction_is_found_and_lowers_heldout_error():
    from calibration.diagnosis.basis import DataBasis
    from calibration.diagnosis.data import load_segment
    from calibration.diagnosis.loop import LoopConfig, diagnose

    train = [load_segment(UR5 / "Movement_No7_Acc_slow_Verify_Model_short.npz")]
    held = [load_segment(UR5 / "Movement_No6_Acc_slow_Verify_Model.npz").slice(0, 4000, "No6[:32s]")]
    assert train[0].units == "A"
    dg = diagnose(DataBasis(6), train, held, LoopConfig(max_effects=2))
    first = dg.steps[1].added
    assert first["effect"] in {"coulomb_friction", "viscous_friction", "stribeck_friction", "backlash"}
    j = first["joint"]
    assert dg.steps[1].heldout_l1[j] < 0.9 * dg.steps[0].heldout_l1[j]
    assert np.mean(dg.steps[-1].heldout_l1) < np.mean(dg.steps[0].heldout_l1)


def test_cli_reads_recordings_one_run_per_episode(tmp_path, capsys):
    from recording_helpers import record_session

    from calibration.diagnosis.data import load_segments

    path = tmp_path / "session.mcap"
    record_session(path, n=1500, dt=0.01, episodes=2, cameras=False, contact=False).close()
    segs = load_segments(path)
    assert [s.name for s in segs] == ["session#ep0", "session#ep1"]
    assert all(len(s) == 1500 and s.units == "N*m" and s.n == 6 for s in segs)
    # tau_m minus the recorded ground truth (0.1 N*m): diagnosis models free-space dynamics
    assert np.allclose(segs[0].tau[:, 0], np.arange(1500) * 0.01 - 0.1, atol=1e-9)
    out = tmp_path / "diag"
    assert main(["diagnose", str(path), "--out", str(out), "--no-plots"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["train_runs"] == ["session#ep0"] and rep["heldout_runs"] == ["session#ep1"]
    capsys.readouterr()
    # with ground-truth contact (0.25 s of every second) only stretches 0.3 s clear of it are kept
    touchy = tmp_path / "touchy.mcap"
    record_session(touchy, n=1500, dt=0.01, episodes=1, cameras=False).close()
    kept = load_segments(touchy)  # the last touch ends at 14.24 s: only the tail from ~14.54 s is kept
    assert [s.name for s in kept] == ["touchy#ep0#0"] and 44 <= len(kept[0]) <= 46
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"garbage" * 50)
    assert main(["diagnose", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.mcap" in err[0], err


def test_free_runs_leave_out_the_samples_near_contact():
    from calibration.diagnosis.data import free_runs

    t = np.arange(1000) * 0.01
    c = np.zeros(1000, bool)
    c[500:505] = True
    assert free_runs(t, c) == [(0, 470), (535, 1000)]  # 0.3 s either side of the touch
    assert free_runs(t, None) == [(0, 1000)] and free_runs(t, np.zeros(1000, bool)) == [(0, 1000)]
    c[:] = False
    c[-1] = True
    assert free_runs(t, c) == [(0, 970)]
    assert free_runs(t[:10], None) == []  # too short to be a run


def test_cli_takes_the_arm_the_logs_name_and_a_flag_overrides(tmp_path, capsys):
    """Logs that name their arm need no --arm (the pinocchio regressor is used); --arm none forces the
    data-only basis; logs naming two different arms are one line."""
    pin = pytest.importorskip("pinocchio")
    from calibration.diagnosis.synthetic import pinocchio_arm

    model = pin.buildSampleModelManipulator()
    paths = []
    for s in range(2):
        g = pinocchio_arm(model, "current_offset", 2, 10.0, seed=s)
        p = tmp_path / f"run{s}.npz"
        np.savez(p, t=g.t, q=g.q, qd=g.qd, q_cmd=g.q, tau_m=g.tau, arm=np.array("pinocchio-sample"),
                 arm_sha256=np.array(""))
        paths.append(str(p))
    out = tmp_path / "named"
    assert main(["diagnose", *paths, "--out", str(out), "--no-plots"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["arm"] == "pinocchio-sample" and rep["arm_source"] == "named by the logs"
    assert "pinocchio" in rep["basis"] and rep["headline"] == capsys.readouterr().out.splitlines()[-3]
    out = tmp_path / "none"
    assert main(["diagnose", *paths, "--arm", "none", "--out", str(out), "--no-plots"]) == 0
    assert "data-only" in json.loads((out / "report.json").read_text())["basis"]
    d = dict(np.load(paths[1]))
    np.savez(paths[1], **{**d, "arm": np.array("piper")})
    capsys.readouterr()
    assert main(["diagnose", *paths, "--out", str(tmp_path / "two"), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different arms" in err[0], err


def test_recordings_name_their_arms_in_the_recording_metadata(tmp_path):
    from recording_helpers import record_session

    from calibration.diagnosis.data import load_segments
    from hardware.recording.metadata import describe_recording, recorded_arm
    from hardware.rigs.rig import load_rig

    meta = describe_recording(rig_path=load_rig("sim-piper").path, twin=True)
    assert recorded_arm(meta, "follower")["arm"] == "piper"
    assert recorded_arm(meta, "follower")["joint_names"][0] == "joint1"
    assert recorded_arm(meta, "leader")["arm"] == "gello_piper" and recorded_arm({}, "follower") == {}
    path = tmp_path / "session.mcap"
    record_session(path, n=300, dt=0.01, episodes=1, cameras=False, contact=False, metadata=meta).close()
    segs = load_segments(path)
    assert segs[0].arm == "piper" and len(segs[0].arm_sha256) == 64


def test_cli_declared_report_of_an_arm_is_its_prior(tmp_path, capsys):
    """With an arm description, a report carries the base parameters it identified; --declared of it pulls the
    next diagnosis toward them (the arm before a change), and a report of another arm is one line, exit 2."""
    pin = pytest.importorskip("pinocchio")
    from calibration.diagnosis.synthetic import pinocchio_arm

    model = pin.buildSampleModelManipulator()
    paths = []
    for s in range(2):
        g = pinocchio_arm(model, None, 1, 8.0, seed=s)
        p = tmp_path / f"run{s}.npz"
        np.savez(p, t=g.t, q=g.q, qd=g.qd, q_cmd=g.q, tau_m=g.tau)
        paths.append(str(p))
    first = tmp_path / "ref"
    arm = ["--arm", "pinocchio-sample", "--no-plots"]
    assert main(["diagnose", *paths, *arm, "--prior-weight", "0.001", "--out", str(first)]) == 0
    rigid = json.loads((first / "report.json").read_text())["rigid_parameters"]
    assert rigid["prior_weight"] == 0.001 and len(rigid["theta"]) == len(rigid["columns"])
    capsys.readouterr()
    assert main(["diagnose", *paths, *arm, "--declared", str(first / "report.json"),
                 "--out", str(tmp_path / "second")]) == 0
    assert "prior: the base parameters identified in ref/report.json" in capsys.readouterr().out
    bad = tmp_path / "bad.json"
    other = {**rigid, "columns": rigid["columns"][1:]}
    bad.write_text(json.dumps({"effects": [], "rigid_parameters": other}))
    assert main(["diagnose", *paths, *arm, "--declared", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not this arm's" in err[0], err
