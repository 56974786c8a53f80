"""Free-motion collection on the twin (SIMULATED sim-piper rig, lockstep) and the contact guard."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.next.collect import ContactStop, Push, collect_free_motion, residual_exceeds
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
    assert run.stopped == ""


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
    assert err.value.run is not None and err.value.run.stopped == "contact"  # the partial run is kept


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
