"""A real-time twin's leaders are held at their start pose by the simulated operator's hand until the app's
loop has them (hardware.sim.twin.Twin.hold_leaders_at_start), then let go (SIMULATED). Unheld, the YAM
GELLO's wrist swung from 0 to -1.75 rad in the 0.3 s before the loop's first read, and `factr2 teleop
--rig sim-yam` refused to start (`j4 1.01-1.03 rad; limit 1.00 rad`) in about 1 of 3 runs (issue #53)."""

from __future__ import annotations

import time

import numpy as np


def _leader_q(twin, name: str = "leader") -> np.ndarray:
    dv = twin.devices[name]
    with dv.world.lock:
        return dv.world.data.qpos[dv.bank.qadr[: dv.n_arm]].copy()


def test_realtime_twin_holds_the_leader_where_it_started():
    from hardware.connect import open_rig

    with open_rig("sim-yam", clock="realtime") as s:  # its drivers connect in 0.2-0.6 s of twin time
        assert s.twin.rig.leaders[0].twin_start_q is None  # the twin starts the leader at 0
        time.sleep(0.5)  # longer than the unheld wrist's fall (0.3 s to its stop)
        sag = np.abs(_leader_q(s.twin))
    # the hand (3 N*m/rad) against the wrist's gravity load (0.13 N*m at most): 0.04 rad
    assert sag.max() < 0.1, f"the leader sagged {np.round(sag, 3)} rad while nothing had it"


def test_the_loop_lets_go_once_it_has_the_leader(monkeypatch):
    import factr2_teleop.teleop.pair as pair
    import hardware.connect as connect
    from factr2_teleop.cli import build_parser
    from factr2_teleop.commands import teleop

    got, mismatch = {}, []
    real_open, real_me = connect.open_rig, pair.mismatch_error

    def open_rig(*a, **k):
        got["session"] = session = real_open(*a, **k)
        return session

    def mismatch_error(q_f, q_goal, max_rad, where="teleop"):
        mismatch.append(np.abs(np.asarray(q_goal) - np.asarray(q_f)))
        return real_me(q_f, q_goal, max_rad, where)

    monkeypatch.setattr(connect, "open_rig", open_rig)
    monkeypatch.setattr(pair, "mismatch_error", mismatch_error)
    out = teleop.execute(build_parser().parse_args(["teleop", "--rig", "sim-yam", "--seconds", "1.0"]))
    assert not [m for _t, _who, m in out["messages"] if "differ too much" in m]
    # the start's check saw the held leader against the follower where its driver found it (its wrist
    # falls to -0.72 rad by itself before connect): well inside the 1 rad limit, not a race
    assert mismatch and mismatch[0].max() < 0.85, np.round(mismatch[0], 3)
    bank = got["session"].twin.devices["leader"].bank
    assert bank._hand_imp is None and not np.any(bank.tau_hand), "the start hand still holds the leader"


def test_a_hand_set_since_is_not_let_go():
    from hardware.rigs.rig import load_rig
    from hardware.sim.twin import Twin

    twin = Twin(load_rig("sim-yam"))
    try:
        twin.hold_leaders_at_start()
        bank = twin.devices["leader"].bank
        assert bank._hand_imp is not None
        tau = np.full(twin.devices["leader"].n_arm, 0.05)
        twin.apply_leader_hand_torque(tau)  # an operator's hand (the demo's, the terminal app's)
        twin.release_start_hold()
        assert np.allclose(bank.tau_hand[: tau.size], tau)
    finally:
        twin.close()
