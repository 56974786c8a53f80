"""Collection that teaches recovery (factr2_teleop/teleop/perturb.py): the offsets as pure functions
(bounded, smooth, zero outside their windows, the same per seed), the pair's command path through the
safety layer, the marks a short twin collection writes, and training reading them (dart / skip)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from teleop_fakes import Rig

from factr2_teleop.teleop import perturb as P
from factr2_teleop.teleop.loop import TeleopLoop
from factr2_teleop.teleop.pair import COUPLED
from hardware.errors import UserError

configs = st.builds(P.PerturbConfig, amplitude_rad=st.floats(0.0, 0.2), ramp_s=st.floats(0.05, 2.0),
                    hold_s=st.floats(0.0, 3.0), gap_min_s=st.floats(0.0, 3.0), gap_mean_s=st.floats(0.1, 5.0),
                    start_s=st.floats(0.0, 3.0))


@settings(max_examples=60, deadline=None)
@given(cfg=configs, seed=st.integers(0, 2**31), n=st.integers(1, 7))
def test_offsets_are_bounded_smooth_zero_outside_windows_and_seeded(cfg, seed, n):
    horizon = 30.0
    wins = P.draw_windows(cfg, seed, n, horizon)
    assert [(t, a.tolist()) for t, a in wins] == [(t, a.tolist()) for t, a in P.draw_windows(cfg, seed, n,
                                                                                               horizon)]
    starts = [t for t, _ in wins]
    assert all(t0 >= cfg.start_s + cfg.gap_min_s for t0 in starts[:1])
    assert all(b - a >= cfg.window_s + cfg.gap_min_s - 1e-9 for a, b in zip(starts, starts[1:]))
    # 250 Hz, the demo's and tests' teleop rate: the step and curvature bounds below scale with dt (no ramp
    # is shorter than 0.05 s: >= 12 samples on it); 500 Hz evaluated offset_at 15 000 times per example
    dt = 0.004
    t = np.arange(0.0, horizon, dt)
    off = np.array([P.offset_at(wins, cfg, x, n) for x in t])
    assert np.all(np.abs(off) <= cfg.amplitude_rad + 1e-12)  # bounded per joint
    inside = np.zeros(len(t), bool)
    for t0, _ in wins:
        inside |= (t > t0) & (t < t0 + cfg.window_s)
    assert np.all(off[~inside] == 0.0)  # zero outside the windows (and before start_s)
    # smooth: no step larger than the steepest slope allows, and the slope itself changes gradually
    assert np.all(np.abs(np.diff(off, axis=0)) <= cfg.max_rate_rad_s() * dt * (1 + 1e-6) + 1e-12)
    curv = cfg.amplitude_rad * (np.pi / cfg.ramp_s) ** 2 / 2  # the raised cosine's largest 2nd derivative
    assert np.all(np.abs(np.diff(off, 2, axis=0)) <= curv * dt * dt * (1 + 1e-6) + 1e-12)


def test_joints_restrict_the_offsets_and_another_seed_draws_others():
    cfg = P.PerturbConfig(joints=(0, 2))
    wins = P.draw_windows(cfg, 7, 6, 60.0)
    assert wins and all(np.all(a[[1, 3, 4, 5]] == 0) and np.any(a[[0, 2]] != 0) for _, a in wins)
    assert [t for t, _ in wins] != [t for t, _ in P.draw_windows(cfg, 8, 6, 60.0)]
    assert P.envelope(np.array([0.0, cfg.ramp_s, cfg.ramp_s + cfg.hold_s, cfg.window_s]), cfg).tolist() == [
        0.0, 1.0, 1.0, 0.0]


def test_settings_parse_and_bad_ones_say_how_to_fix():
    assert P.parse_perturb("on") == P.PerturbConfig()
    c = P.parse_perturb("amplitude_rad=0.02, hold_s=1.5,joints=0+1")
    assert (c.amplitude_rad, c.hold_s, c.joints) == (0.02, 1.5, (0, 1))
    for bad in ("amplitude=0.1", "hold_s=x"):
        with pytest.raises(UserError, match="bad perturbation setting"):
            P.parse_perturb(bad)
    with pytest.raises(UserError, match="above 0"):
        P.parse_perturb("ramp_s=0").validate(6)
    with pytest.raises(UserError, match="outside 0..5"):
        P.parse_perturb("joints=6").validate(6)


def test_the_offset_goes_through_the_follower_safety_layer():
    """An offset beyond the joint limit and the rate limit reaches the follower clipped; the operator's
    target stays unperturbed and the tick records the offset asked."""
    plain = Rig(q_leader=[1.9, 0.0, 0.0], q_follower=[1.9, 0.0, 0.0])
    recs = []
    TeleopLoop([plain.pair()], plain.clock, recorder=recs.append).run(duration_s=0.2)
    assert recs and all(r.perturb_q is None for r in recs)  # no perturbation: nothing to record

    rig = Rig(q_leader=[1.9, 0.0, 0.0], q_follower=[1.9, 0.0, 0.0])
    pair = rig.pair()
    big = np.array([0.5, 0.0, 0.0])  # 1.9 + 0.5 rad: past q_max 2.0, and in one tick past v_max
    pair.perturb = lambda t: big if t >= 0.5 else np.zeros(3)
    recs = []
    TeleopLoop([pair], rig.clock, recorder=recs.append).run(duration_s=1.0)
    coupled = [r for r in recs if r.phase == COUPLED]
    before = [r for r in coupled if r.t < 0.5]
    after = [r for r in coupled if r.t >= 0.5]
    assert before and after
    assert all(np.array_equal(r.perturb_q, big) for r in after)
    assert all(np.array_equal(r.perturb_q, np.zeros(3)) for r in before)
    q = np.array([r.action_q[0] for r in before[-1:] + after])  # what the safety layer let through
    t = np.array([r.t for r in before[-1:] + after])
    assert np.all(q <= 2.0 + 1e-12) and q.max() > 1.95  # pushed to the joint limit, never past it
    assert np.all(np.abs(np.diff(q)) <= 10.0 * np.diff(t) + 1e-9)  # v_max 10 rad/s: no jump of 0.5 rad
    q_f = np.array([r.follower.q[0] for r in after])
    assert np.all(q_f <= 2.0 + 1e-6) and abs(q_f[-1] - 2.0) < 0.01  # the follower went to the limit
    assert abs(pair.q_target[0] - 1.9) < 0.05  # the operator's target is not the perturbed one
    assert rig.follower.safety.clipped > 0


def test_a_short_twin_collection_marks_its_perturbed_ticks_and_training_reads_them(tmp_path):
    pytest.importorskip("mujoco")
    from factr2_teleop.tasks.run import CollectConfig, collect
    from hardware.recording import schemas as S
    from hardware.recording.reader import Recording
    from policies.data.dataset import build_dataset
    from policies.data.recordings import load_episodes

    cfg = P.PerturbConfig(start_s=0.5, gap_min_s=0.5, gap_mean_s=0.5)
    out = collect(CollectConfig(task="wipe", episodes=1, out=str(tmp_path), seed=0, mode="ground_truth",
                                cameras=False, perturb=cfg), progress=False)
    assert out["perturb"] == cfg.to_dict()
    from factr2_teleop.tasks.run import summary_lines

    assert any("perturbed  +-0.04 rad on every joint, windows of 1.6 s" in x for x in summary_lines(out))
    rec = Recording(out["recording"])
    assert rec.info["perturb"] and S.perturb_topic("follower") in rec.topics
    (ep,) = rec.episodes
    off = ep.topic(S.perturb_topic("follower"))
    cmd = ep.topic(S.command_topic("follower"))
    assert len(off) > 0.9 * len(cmd)  # every coupled tick of the episode carries its offset
    hit = np.any(off.fields["offset"] != 0, axis=1)
    assert 0 < hit.mean() < 1 and np.abs(off.fields["offset"]).max() <= cfg.amplitude_rad + 1e-9
    # the windows recorded are the episode seed's (the same pure function)
    wins = P.draw_windows(cfg, out["results"][0]["seed"], off.fields["offset"].shape[1], 1000.0)
    t_first = off.t[np.argmax(hit)] - ep.t_start
    assert any(t0 - 0.05 <= t_first <= t0 + 0.05 for t0, _ in wins), (t_first, [w[0] for w in wins[:3]])

    eps, arms = load_episodes([out["recording"]], keep_discarded=True)
    kw = dict(th=None, chunk=4, force="none", observation="joints", val_fraction=0.0)
    dart = build_dataset(eps, arms, **kw)
    skip = build_dataset(eps, arms, perturbed="skip", **kw)
    assert dart.perturbed is not None and 0 < dart.perturbed.mean() < 1
    p = dart.perturbed
    # dart: the operator's target (command minus offset); skip: the command, its perturbed steps masked
    grid_cmd = skip.action[p, 0, :6] - dart.action[p, 0, :6]
    assert np.abs(grid_cmd).max() > 1e-3 and np.abs(grid_cmd).max() <= cfg.amplitude_rad + 1e-6
    assert np.array_equal(dart.action[~p, 0], skip.action[~p, 0])
    assert not skip.mask[p, 0].any() and dart.mask[p, 0].all()

    # `factr2 train --perturbed skip` on it: the run counts its perturbed samples and names the mode
    from factr2_teleop.cli import main
    from policies.training import checkpoint as C

    run = tmp_path / "run"
    assert main(["train", str(out["recording"]), "--out", str(run), "--obs", "joints", "--method", "base",
                 "--steps", "3", "--batch", "8", "--warmup", "1", "--include-failed", "--no-progress",
                 "--threads", "1", "--perturbed", "skip"]) == 0
    meta = C.read_meta(run)
    assert meta["perturbed"] == "skip" and meta["samples"]["perturbed"] > 0


@pytest.mark.parametrize("settings,says", [("amplitude=0.1", "bad perturbation setting"),
                                           ("joints=9", "outside 0..5"), ("ramp_s=0", "above 0")])
def test_bad_perturbation_settings_are_one_line_and_nothing_is_written(tmp_path, capsys, settings, says):
    from factr2_teleop.cli import main

    assert main(["collect", "--task", "wipe", "--episodes", "1", "--out", str(tmp_path), "--mode", "dob",
                 "--perturb", settings]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0] and "--perturb" in err[0], err
    assert not any(tmp_path.iterdir())
