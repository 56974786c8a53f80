"""cap-screw (SIMULATED): the stage detectors on scripted states (success, loose, over-tight, stripped and
latched), seeded resets, what a camera may see (no hidden parameter), the thread's physics (pitch, seating,
self-locking) and a demonstration script that reads neither the truth nor the episode's parameters."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from hardware.arms import load_arm
from hardware.sim.tasks import cap_screw as C
from hardware.sim.tasks import get_task, scene_model

HIDDEN = ("_friction_nm", "_gasket_tc_s", "_strip_nm", "_turns_to_seat")


def _obs(turn=0.0, clamp=0.0, fingers=(False, False)):
    return {"cap_turn": np.array(turn), "clamp_n": np.array(clamp), "finger_touch": np.array(fingers)}


def _clamp_for(tau_nm):
    return tau_nm / C.TIGHT_R_M


PARAMS = {"jar_pos": np.zeros(3), "jar_yaw": 0.0, "_strip_nm": 0.2}


def test_stages_from_scripted_states():
    mem = {}
    assert C.detect_cap(_obs(), PARAMS, mem).tolist() == [False, False, False, False]
    assert C.detect_cap(_obs(fingers=(True, False)), PARAMS, mem)[0] == np.False_  # one finger
    assert C.detect_cap(_obs(0.5, fingers=(True, True)), PARAMS, mem).tolist() == [True, False, False, False]
    assert C.detect_cap(_obs(C.ENGAGE_RAD + 0.01, fingers=(True, True)), PARAMS, mem)[1]
    seated = C.detect_cap(_obs(6.0, C.SEAT_N + 1.0, (True, True)), PARAMS, mem)
    assert seated.tolist() == [True, True, True, False]  # seated, loose
    mid = _clamp_for(np.mean(C.TIGHT_BAND_NM))
    assert not C.detect_cap(_obs(6.0, mid, (True, True)), PARAMS, mem)[3]  # in band but still held
    assert C.detect_cap(_obs(6.0, mid, (False, False)), PARAMS, mem)[3]  # released in band: tight
    assert not C.detect_cap(_obs(6.0, _clamp_for(C.TIGHT_BAND_NM[0] - 0.005)), PARAMS, mem)[3]  # loose
    assert not C.detect_cap(_obs(6.0, _clamp_for(C.TIGHT_BAND_NM[1] + 0.005)), PARAMS, mem)[3]  # over
    assert "stripped" not in mem


def test_strip_latches():
    mem = {}
    mid = _clamp_for(np.mean(C.TIGHT_BAND_NM))
    assert C.detect_cap(_obs(6.0, mid), PARAMS, mem)[3]
    C.detect_cap(_obs(6.0, _clamp_for(PARAMS["_strip_nm"] + 0.01), (True, True)), PARAMS, mem)
    assert mem["stripped"] and mem["peak_nm"] > PARAMS["_strip_nm"]
    assert not C.detect_cap(_obs(6.0, mid), PARAMS, mem)[3]  # back in the band: still stripped
    task = get_task("cap-screw")
    assert not task.final_ok(_obs(6.0, mid), PARAMS, mem)
    assert task.final_ok(_obs(6.0, mid), PARAMS, {})


def test_band_below_strip_and_metrics():
    assert C.TIGHT_BAND_NM[1] < C.STRIP_NM[0]  # every in-band tightening survives every episode's thread
    m = C.cap_metrics(1.0, 10.0, (True, True))
    assert m["tau_tight_nm"] == pytest.approx(10.0 * C.TIGHT_R_M) and m["held"] and not m["released"]
    assert C.cap_metrics(1.0, -3.0, (False, False))["tau_tight_nm"] == 0.0


def _scene():
    task = get_task("cap-screw")
    m = scene_model(load_arm("piper"), "table", task)
    return task, m, mujoco.MjData(m)


def test_reset_is_seeded_and_detectables_hide_the_thread():
    from policies.data.privileged import objects_vector

    task, m, d = _scene()
    p1 = task.reset(m, d, np.random.default_rng(3))
    q1 = d.qpos.copy()
    p2 = task.reset(m, d, np.random.default_rng(3))
    assert all(np.allclose(p1[k], p2[k]) for k in p1) and np.allclose(q1, d.qpos)
    p3 = task.reset(m, d, np.random.default_rng(4))
    assert not np.allclose(p3["jar_pos"], p1["jar_pos"]) and p3["_friction_nm"] != p1["_friction_nm"]
    assert set(HIDDEN) <= set(p1)
    mujoco.mj_forward(m, d)
    det = task.detectables(m, d, p3)
    assert set(det) == {"cap", "jar"}  # poses only: the contract's (position, rotation) pairs
    # the hidden thread does not change what a camera sees
    m.dof_frictionloss[m.joint("cap_turn").dofadr[0]] *= 3
    det2 = task.detectables(m, d, {**p3, "_strip_nm": 9.0})
    assert all(np.allclose(det[k][0], det2[k][0]) and np.allclose(det[k][1], det2[k][1]) for k in det)
    obs = task.observe(m, d, p3)
    assert not set(HIDDEN) & set(obs)
    _, names = objects_vector(obs, p3)
    assert not any(n.startswith("_") for n in names)  # nor does the privileged vector hold them


def _turn(m, d, task, params, stop_nm, seconds, hand_k=2.0, rate=1.0):
    """A hand on the lid's hinge (a stiff spring dragged at `rate` rad/s) until its torque reaches stop_nm,
    then let go; returns per-step (time, turn, drop, clamp) after letting go, and the turn at letting go."""
    tj, dj = m.joint("cap_turn"), m.joint("cap_drop")
    ref, held, rows, turn_at_release = 0.0, True, [], None
    for _ in range(round(seconds / m.opt.timestep)):
        th, om = d.qpos[tj.qposadr[0]], d.qvel[tj.dofadr[0]]
        tau = 0.0
        if held:
            ref += rate * m.opt.timestep
            tau = hand_k * (ref - th) - 0.05 * om
            if tau > stop_nm:
                held, turn_at_release = False, th
        d.qfrc_applied[tj.dofadr[0]] = tau
        mujoco.mj_step(m, d)
        if not held:
            rows.append((d.time, d.qpos[tj.qposadr[0]], d.qpos[dj.qposadr[0]],
                         float(task.observe(m, d, params)["clamp_n"])))
    return np.array(rows), turn_at_release


def test_thread_pitch_seat_and_self_locking():
    task, m, d = _scene()
    params = task.reset(m, d, np.random.default_rng(1))
    mujoco.mj_forward(m, d)
    offset = m.eq_data[m.equality("cap_thread").id, 0]
    rows, th_release = _turn(m, d, task, params, stop_nm=0.16, seconds=9.0)
    assert th_release is not None, "the lid never tightened"
    seat_turn = params["_turns_to_seat"] * 2 * np.pi
    assert seat_turn < th_release < seat_turn + 1.0  # it tightened just past where it seats
    t, turn, drop, clamp = rows.T
    # the thread: one pitch of drop per turn (within 0.5 mm while clamped)
    assert abs(drop[-1] - offset - C.LEAD_M_PER_RAD * turn[-1]) < 0.0005
    # released: the clamp holds (the gasket's friction self-locks the thread): no unwinding
    after = t > t[0] + 0.3
    assert clamp[after].min() > 0.9 * clamp[after].max() > 0
    assert turn[after].max() - turn[after].min() < 0.01


class _Poisoned(dict):
    """Episode params / truth the demonstrator must never read."""

    def __getitem__(self, k):
        raise AssertionError(f"the cap-screw script read {k!r}")

    get = items = keys = values = __iter__ = __getitem__


def test_script_reads_neither_truth_nor_params():
    from factr2_teleop.tasks.operator import Operator, Percept
    from factr2_teleop.tasks.screw import cap_screw
    from hardware.arms.dynamics import ArmDynamics
    from hardware.sim.perception import Seen

    dyn = ArmDynamics(load_arm("piper"))
    lo = np.array([-2.6, 0.0, -2.96, -1.74, -1.22, -2.09])  # the Piper's joint limits [rad]
    hi = np.array([2.6, 3.14, 0.0, 1.74, 1.22, 2.09])
    op = Operator(dyn.fk, dyn.jacobian, lo, hi, lambda q: q, 0.002, np.array([0.0, 1.2, -1.0, 0.0, 0.6, 0.0]))
    seen = {"cap": Seen(np.array([0.3, 0.02, 0.055]), np.eye(3), 0.1, True),
            "jar": Seen(np.array([0.3, 0.02, 0.0]), np.eye(3), 0.1, True)}

    def percept(t):  # the arm where the reference is; a lid that resists once the wrist has turned a lot
        T = dyn.fk(op.q_des)
        tau = np.zeros(6)
        tau[5] = -0.04 if op.grip > 0.5 else 0.0
        return Percept(t=t, q_leader=op.q_des, qd_leader=np.zeros(6), trigger=op.grip, q_follower=op.q_des,
                       felt_nm=0.0, T_ee=T, obs=_Poisoned(), seen=seen, tau_ext=tau)

    op.p = percept(0.0)
    script = cap_screw(op, _Poisoned(), np.random.default_rng(0))
    for k in range(1500):  # 15 s of decisions: look, reach, probe twice, the first strokes
        op.p = percept(0.01 * k)
        next(script)
    assert op.log["strokes"] >= 1 and op.log["centred_mm"] == [0.0, 0.0]
