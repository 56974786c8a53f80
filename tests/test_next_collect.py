"""Free-motion collection on the twin (SIMULATED sim-piper rig, lockstep) and the contact guard."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.next.collect import CollectStop, ContactStop, Push, collect_free_motion, residual_exceeds
from calibration.trajectories import PHASES, Trajectory, ruckig_move


def test_residual_guard():
    tau_max = np.array([10.0, 2.0])
    assert not residual_exceeds(np.array([2.9, 0.5]), tau_max, 0.3)
    assert residual_exceeds(np.array([0.0, -0.7]), tau_max, 0.3)


def _short_traj(arm, seconds_per_move=1.0):
    home = np.asarray(arm.q_home, float)
    target = home.copy()
    target[0] += 0.3
    v = arm.limits.v_max * 0.3
    q, qd, qdd = ruckig_move(home, target, v, 2 * v, 20 * v, 100.0)
    n = len(q)
    return Trajectory(t=np.arange(n) / 100.0, q=q, qd=qd, qdd=qdd, phase=np.full(n, PHASES.index("single")),
                      rate_hz=100.0, joint_names=list(arm.joint_names), arm=arm.name)


def test_collect_on_twin_records_free_motion():
    sim = pytest.importorskip("hardware.connect")
    from hardware.arms import load_arm

    arm = load_arm("piper")
    traj = _short_traj(arm)
    seen = []
    with sim.open_rig("sim-piper", clock="lockstep") as session:
        run = collect_free_motion(session, "follower", traj, progress=lambda d, t: seen.append((d, t)))
    a = run.arrays()
    assert a["q"].shape == (len(traj.t), 6) and a["tau_m"].shape == a["q"].shape
    assert np.all(np.diff(a["t"]) > 0) and seen[-1][0] == pytest.approx(seen[-1][1])
    assert np.abs(a["q"][-1] - traj.q[-1]).max() < 0.05  # the follower tracked the replayed motion
    assert "tau_ext_true" in a and not a["contact"].any()  # simulated ground truth: free motion
    assert run.stopped is None


def test_contact_guard_stops_and_holds():
    sim = pytest.importorskip("hardware.connect")
    from hardware.arms import load_arm

    arm = load_arm("piper")
    traj = _short_traj(arm)
    with sim.open_rig("sim-piper", clock="lockstep") as session:
        # a guard so tight that ordinary free-motion residuals trip it: proves the stop path holds the arm
        with pytest.raises(ContactStop) as err:
            collect_free_motion(session, "follower", traj, contact_frac=1e-6, contact_ticks=2)
        assert session.followers["follower"].in_safe_state
    assert err.value.run is not None  # the partial run is kept
    assert err.value.run.stopped.kind is CollectStop.CONTACT


def test_scripted_push_is_labelled_contact_with_ground_truth():
    sim = pytest.importorskip("hardware.connect")
    from hardware.arms import load_arm

    arm = load_arm("piper")
    traj = _short_traj(arm)
    with sim.open_rig("sim-piper", clock="lockstep") as session:
        push = Push(0.3, "link6", (0.0, 0.0, -30.0), 0.2)
        run = collect_free_motion(session, "follower", traj, pushes=[push])
    a = run.arrays()
    t = a["t"] - a["t"][0]
    pushed = (t > 0.32) & (t < 0.48)
    assert a["contact"][pushed].all() and not a["contact"][t < 0.25].any() and not a["contact"][t > 0.6].any()
    assert np.abs(a["tau_ext_true"][pushed]).max() > 1.0  # the push shows in the twin's ground truth [N*m]


def test_rig_calibration_is_recorded_as_mcap_and_calibrates_from_it(tmp_path):
    """Issue 23, item 6: a calibration run on a rig is one MCAP session (free-motion replay and, on a twin,
    the pushed contact replay as episodes), and `factr2 calibrate --from-logs` accepts it (the pushes are
    left out of training by their contact flag)."""
    sim = pytest.importorskip("hardware.connect")
    from calibration.next.logs import read_logs
    from calibration.next.train import TrainConfig
    from calibration.pipeline import CalibrationConfig, calibrate_rig
    from calibration.report import calibrate_from_logs
    from hardware.recording.reader import Recording

    tiny = TrainConfig(history=10, hidden=8, head_hidden=16, samples_per_epoch=256, max_epochs=1, threads=1,
                       device="cpu", prior="none")
    cfg = CalibrationConfig(minutes=0.2, contact_eval_s=4.0, train=tiny, plots=False, min_minutes=0.05)
    said = []
    with sim.open_rig("sim-piper", clock="lockstep") as session:
        calibrate_rig(session, session.rig.followers[0], tmp_path / "cal", cfg, say=said.append)
    mcap = tmp_path / "cal" / "data" / "calibration.mcap"
    assert mcap.is_file() and any("calibration.mcap" in s for s in said)
    rec = Recording(mcap)
    assert len(rec.episodes) == 2 and rec.info["simulated"] == "true"
    runs = read_logs(mcap)
    free = np.load(tmp_path / "cal" / "data" / "free_motion.npz")
    assert len(runs[0].log.t) == len(free["t"]) and np.allclose(runs[0].log.q, free["q"])
    assert np.allclose(runs[0].log.q_cmd, free["q_cmd"]) and runs[0].log.arm == "piper"
    assert runs[1].log.contact.any()  # the pushes, with the twin's ground truth
    rep = calibrate_from_logs([mcap], tmp_path / "again", cfg=tiny, plots=False)
    n_free = sum(int((~r.log.contact).sum()) if r.log.contact is not None else len(r.log.t) for r in runs)
    assert rep["data_minutes"] * 60 * 100 < n_free  # contact samples (and a margin) were not trained on
    assert rep["arm"] == "piper" and rep["prior"] == "none"
