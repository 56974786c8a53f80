"""Rollout chunk scheduling as pure functions: ACT temporal-ensembling weights, flow receding horizon,
interpolation from the policy rate to the loop rate, the age of the executed action, refusals and stalls;
and which NEXT checkpoint a policy names."""

import hashlib
import json

import numpy as np
import pytest

from calibration.next.ident import NextId
from factr2_teleop.session.rollout import NextNote, resolve_next
from hardware.errors import UserError
from policies.rollout.schedule import (
    ACT_ENSEMBLE_M,
    ENSEMBLE,
    RECEDING,
    STALL_S,
    Chunk,
    ChunkSchedule,
    PolicyHold,
    chunk_problem,
    ensemble_weights,
    ensembled_stacked,
    ensembled_target,
    interp_chunk,
    limit_tolerance,
    overdue_s,
    receding_target,
    request_period_s,
    stack_chunks,
)

DT = 0.1
LIM = (np.full(2, -1.0), np.full(2, 1.0))


def ramp(t_obs, h=5, slope=1.0, offset=0.0):
    """A chunk whose joint targets equal slope * (time - 0) + offset, gripper 0."""
    t = t_obs + DT * np.arange(h)
    a = np.stack([slope * t + offset, -slope * t, np.zeros(h)], 1)
    return Chunk(t_obs=t_obs, actions=a, dt=DT)


def test_ensemble_weights_are_the_original_act_exponential_oldest_first():
    w = ensemble_weights(4, 0.01)
    np.testing.assert_allclose(w, np.exp(-0.01 * np.arange(4)) / np.exp(-0.01 * np.arange(4)).sum())
    assert w[0] > w[-1] and abs(w.sum() - 1) < 1e-12
    np.testing.assert_allclose(ensemble_weights(3, 0.0), np.full(3, 1 / 3))
    assert ensemble_weights(2, 5.0)[0] > 0.99  # a large m trusts the oldest prediction


def test_interpolation_between_chunk_steps_and_used_up():
    c = ramp(1.0)
    np.testing.assert_allclose(interp_chunk(c.actions, c.t_obs, DT, 1.0 + 0.25 * DT)[0], 1.025)
    np.testing.assert_allclose(interp_chunk(c.actions, c.t_obs, DT, 0.5), c.actions[0])  # before: first
    np.testing.assert_allclose(interp_chunk(c.actions, c.t_obs, DT, c.t_end), c.actions[-1])
    assert interp_chunk(c.actions, c.t_obs, DT, c.t_end + 1e-3) is None


def test_temporal_ensembling_weights_every_chunk_covering_now():
    old, new = ramp(0.0, offset=0.0), ramp(0.1, offset=0.3)
    a, k = ensembled_target([old, new], 0.2, m=0.01)
    w = ensemble_weights(2, 0.01)
    np.testing.assert_allclose(a[0], w[0] * 0.2 + w[1] * 0.5)
    assert k == 1
    a, k = ensembled_target([old, new], 0.45, m=0.01)  # the old chunk ends at 0.4: only the new one
    np.testing.assert_allclose(a[0], 0.75)
    assert ensembled_target([old], 1.0) == (None, -1)


def _by_chunk(chunks, t, m):
    """The reference: each chunk interpolated on its own (interp_chunk), weighted oldest first."""
    vals = [(k, interp_chunk(c.actions, c.t_obs, c.dt, t)) for k, c in enumerate(chunks)]
    vals = [(k, a) for k, a in vals if a is not None]
    if not vals:
        return None, -1
    return np.tensordot(ensemble_weights(len(vals), m), np.stack([a for _, a in vals]), axes=1), vals[-1][0]


@pytest.mark.parametrize("h", [1, 2, 5, 30])
def test_stacked_ensembling_equals_interpolating_chunk_by_chunk(h):
    """The loop's stacked path (all chunks at once) gives the chunk-by-chunk target at every time: before a
    chunk starts, between its steps, on its last step, past its end, with none left."""
    rng = np.random.default_rng(h)
    chunks = [Chunk(t_obs=0.03 * k, actions=rng.normal(size=(h, 7)), dt=0.034) for k in range(12)]
    edges = [-0.5, 0.0, 0.03 * 11, 0.03 * 11 + 0.034 * (h - 1)]
    for t in np.concatenate([edges, rng.uniform(-0.1, 2.0, 300)]):
        want, k_want = _by_chunk(chunks, t, 0.01)
        got, k = ensembled_stacked(*stack_chunks(chunks), t, 0.01)
        assert k == k_want and (got is None) == (want is None), t
        if want is not None:
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert stack_chunks([]) is None
    mixed = chunks[:2] + [Chunk(t_obs=0.1, actions=np.zeros((h + 1, 7)), dt=0.034)]
    assert stack_chunks(mixed) is None  # different lengths: chunk by chunk
    np.testing.assert_allclose(ensembled_target(mixed, 0.1)[0], _by_chunk(mixed, 0.1, ACT_ENSEMBLE_M)[0])


def test_receding_horizon_runs_the_newest_chunk_and_requests_every_k_steps():
    a, k = receding_target([ramp(0.0), ramp(0.1, offset=0.3)], 0.15)
    np.testing.assert_allclose(a[0], 0.45)
    assert k == 1
    assert request_period_s(RECEDING, DT, 3) == pytest.approx(0.3)
    assert request_period_s(ENSEMBLE, DT, 3) == pytest.approx(DT)
    assert overdue_s(1.0, 0.5, 0.3) == pytest.approx(0.2)


def test_schedule_age_refusals_and_stall():
    s = ChunkSchedule(mode=RECEDING, dt=DT, q_min=LIM[0], q_max=LIM[1], k_exec=2)
    assert s.target(0.0)[0] is None and s.target(0.0)[1].kind is PolicyHold.FIRST_CHUNK
    assert s.add(ramp(0.0, slope=0.5)) is None
    a, why, age = s.target(0.13)
    assert why is None and age == pytest.approx(0.13) and a[0] == pytest.approx(0.065)
    # late by less than STALL_S after the next chunk was due (0.2 s): still running
    assert s.target(0.2 + STALL_S - 0.01)[0] is not None
    a, why, _ = s.target(0.2 + STALL_S + 0.01)
    assert a is None and why.kind is PolicyHold.STALLED
    bad = ramp(0.3)
    nan = Chunk(t_obs=0.3, actions=np.where(np.arange(3) == 1, np.nan, bad.actions), dt=DT)
    assert s.add(nan).kind is PolicyHold.NOT_FINITE and s.nonfinite == 1
    assert s.target(0.31)[0] is None and s.chunks == []
    far = Chunk(t_obs=0.4, actions=bad.actions + np.array([5.0, 0.0, 0.0]), dt=DT)
    why = s.add(far)
    assert why.kind is PolicyHold.OUTSIDE_LIMITS and why.get("joint") == 1 and s.outside_limits == 1
    assert "outside the joint limits (joint 1" in str(why)  # the message rendered from it
    assert s.target(0.41)[0] is None
    assert s.add(ramp(0.5, slope=0.1)) is None  # a good chunk ends the hold
    assert s.target(0.55)[0] is not None


def test_chunk_problem_judges_joints_not_the_gripper():
    a = np.zeros((3, 3))
    a[:, 2] = 7.0  # gripper column: clamped by the caller, never a refusal
    assert chunk_problem(a, *LIM) is None
    a[1, 1] = -1.5
    assert chunk_problem(a, *LIM).get("joint") == 2
    assert chunk_problem(a, *LIM, tol=0.6) is None


def test_the_next_checkpoint_a_policy_names(tmp_path):
    ck = tmp_path / "next.json"
    ck.write_text(json.dumps({"data_hash": "abcdef0123456789"}))
    sha = hashlib.sha256(ck.read_bytes()).hexdigest()[:12]
    assert NextId.parse(f"{ck}#abcdef012345").matches(ck)
    assert not NextId.parse(f"{ck}#000000000000").matches(ck)
    assert NextId.parse(f"next@{sha}").matches(ck) and not NextId.parse("next@000000000000").matches(ck)
    assert resolve_next({"next_checkpoint": f"{ck}#abcdef012345"}, None) == (ck, None)
    assert resolve_next({"next_checkpoint": f"{ck}@{sha}"}, None) == (ck, None)  # the one form today
    assert resolve_next({"next_checkpoint": ""}, None) == (None, None)
    with pytest.raises(UserError, match="not here"):
        resolve_next({"next_checkpoint": f"{tmp_path}/gone.json#abcdef012345"}, None)
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"data_hash": "ffff"}))
    path, note = resolve_next({"next_checkpoint": f"{ck}#abcdef012345"}, other)
    assert path == other and note.kind is NextNote.NOT_TRAINED_WITH
    assert "NOT the checkpoint the policy was trained with" in str(note)


def test_only_the_steps_that_can_run_are_judged_against_the_limits():
    """Receding: the k_exec steps before the next chunk plus those a late one (up to stall_s) would use; a
    target beyond a limit after them is never executed and does not refuse the chunk. Ensembling uses every
    step. A non-finite value anywhere still refuses it (the model is broken)."""
    q_min, q_max = np.array([-1.0]), np.array([1.0])
    s = ChunkSchedule(RECEDING, DT, q_min, q_max, k_exec=3, stall_s=2 * DT, tol=0.0)
    n = s.executable_steps(30)
    assert n == 3 + 2 + 1
    a = np.zeros((30, 1))
    a[n:] = 5.0  # far beyond the limit, but only where it can never run
    assert s.add(Chunk(t_obs=0.0, actions=a, dt=DT)) is None
    a[n - 1] = 5.0
    assert s.add(Chunk(t_obs=0.1, actions=a, dt=DT)).kind is PolicyHold.OUTSIDE_LIMITS
    a[:] = 0.0
    a[-1] = np.nan
    assert s.add(Chunk(t_obs=0.2, actions=a, dt=DT)).kind is PolicyHold.NOT_FINITE
    e = ChunkSchedule(ENSEMBLE, DT, q_min, q_max, tol=0.0)
    assert e.executable_steps(30) == 30
    # the late chunk's furthest step that target() can still reach is inside the judged part
    b = np.zeros((30, 1))
    assert s.add(Chunk(t_obs=1.0, actions=b, dt=DT)) is None
    t_last = 1.0 + s.period_s + s.stall_s - 1e-9
    assert s.target(t_last)[0] is not None and (t_last - 1.0) / DT <= n - 1


def test_an_overshoot_at_a_limit_is_clamped_not_refused_a_wild_target_is():
    """A policy working at a joint limit overshoots it (flow samples: 0.15-0.43 rad past a 0 limit, measured):
    within a quarter of the joint's range the chunk runs (the safety layer clamps it); beyond: refused."""
    q_min, q_max = np.array([-3.0, -1.0]), np.array([0.0, 1.0])  # ranges 3 and 2 rad
    np.testing.assert_allclose(limit_tolerance(q_min, q_max), [0.75, 0.5])
    s = ChunkSchedule(mode=ENSEMBLE, dt=DT, q_min=q_min, q_max=q_max)
    over = Chunk(t_obs=0.0, actions=np.array([[0.43, 0.0, 0.0]] * 5), dt=DT)
    assert s.add(over) is None and s.outside_limits == 0 and s.target(0.01)[0] is not None
    wild = Chunk(t_obs=0.1, actions=np.array([[0.0, 1.6, 0.0]] * 5), dt=DT)  # 0.6 rad past a 2 rad joint
    why = s.add(wild)
    assert why.kind is PolicyHold.OUTSIDE_LIMITS and why.get("joint") == 2 and s.outside_limits == 1
    assert s.target(0.11)[0] is None  # held until a good chunk
