"""Bad input to `factr2 train` / `factr2 episodes phases`: one line, exit 2, nothing written; offline NEXT."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from factr2_teleop.cli import main
from tests.policy_helpers import write_recording

FAST = [
    "--steps",
    "2",
    "--batch",
    "4",
    "--warmup",
    "1",
    "--backbone",
    "convnet-gn",
    "--image-size",
    "32",
    "--set",
    "hidden=32",
    "--set",
    "heads=2",
    "--set",
    "enc_layers=1",
    "--set",
    "dec_layers=1",
    "--set",
    "ff=64",
    "--no-progress",
    "--threads",
    "1",
]


def _train(capsys, *args):
    rc = main(["train", *map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _one_line_error(rc, err, *words):
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("factr2 ")]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    d = tmp_path_factory.mktemp("good")
    write_recording(d / "a.mcap", episodes=2, seconds=2.0)
    return d


def test_no_episodes(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    rc, _, err = _train(capsys, tmp_path / "empty", "--out", tmp_path / "run", "--thresholds", "1:3", *FAST)
    _one_line_error(rc, err, "no recordings")
    assert not (tmp_path / "run").exists()


def test_different_arms_or_joint_sets(tmp_path, capsys):
    write_recording(tmp_path / "a.mcap", episodes=1, seconds=1.0)
    write_recording(tmp_path / "b.mcap", episodes=1, seconds=1.0, n_joints=5)
    rc, _, err = _train(capsys, tmp_path, "--out", tmp_path / "run", "--thresholds", "1:3", *FAST)
    _one_line_error(rc, err, "different arms or joint sets", "b.mcap")
    assert not (tmp_path / "run").exists()


def test_no_frames(tmp_path, capsys):
    write_recording(tmp_path / "a.mcap", episodes=2, seconds=1.0, cameras=())
    rc, _, err = _train(capsys, tmp_path, "--out", tmp_path / "run", "--thresholds", "1:3", *FAST)
    _one_line_error(rc, err, "no camera frames")
    assert not (tmp_path / "run").exists()


def test_no_tau_ext_and_no_next(tmp_path, capsys):
    write_recording(tmp_path / "a.mcap", episodes=2, seconds=1.0, tau_ext=False)
    rc, _, err = _train(capsys, tmp_path, "--out", tmp_path / "run", "--thresholds", "1:3", *FAST)
    _one_line_error(rc, err, "no estimated tau_ext", "--next")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("ratio", ["1:5", "1:-5:1", "0:0:0", "x"])
def test_bad_ratio(good, tmp_path, capsys, ratio):
    rc, _, err = _train(capsys, good, "--out", tmp_path / "run", "--ratio", ratio, *FAST)
    _one_line_error(rc, err, "--ratio", "non-negative")
    assert not (tmp_path / "run").exists()


def test_corrupt_recording_is_skipped_when_others_remain(good, tmp_path, capsys):
    d = tmp_path / "mixed"
    d.mkdir()
    (d / "a.mcap").write_bytes((good / "a.mcap").read_bytes())
    (d / "bad.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)  # a header, then garbage
    (d / "junk.mcap").write_bytes(b"not an mcap at all")
    with pytest.warns(UserWarning, match="skipped"):
        rc, out, err = _train(capsys, d, "--out", tmp_path / "run", "--thresholds", "1:3", *FAST)
    assert rc == 0, err
    only_bad = tmp_path / "bad"
    only_bad.mkdir()
    (only_bad / "junk.mcap").write_bytes(b"not an mcap at all")
    with pytest.warns(UserWarning):
        rc, _, err = _train(capsys, only_bad, "--out", tmp_path / "run2", "--thresholds", "1:3", *FAST)
    _one_line_error(rc, err, "no usable episodes")
    assert not (tmp_path / "run2").exists()


def test_resume_from_another_configuration(good, tmp_path, capsys):
    run = tmp_path / "run"
    rc, _, err = _train(capsys, good, "--out", run, "--thresholds", "1:3", *FAST)
    assert rc == 0, err
    rc, _, err = _train(capsys, good, "--out", run, "--thresholds", "1:3", *FAST)
    _one_line_error(rc, err, "already holds a training run", "--resume")
    before = sorted(p.name for p in (run / "checkpoints").iterdir())
    rc, _, err = _train(
        capsys, good, "--out", run, "--thresholds", "1:3", "--resume", "--ratio", "1:1:5", *FAST
    )
    _one_line_error(rc, err, "another configuration", "ratio")
    rc, _, err = _train(capsys, good, "--out", tmp_path / "none", "--thresholds", "1:3", "--resume", *FAST)
    _one_line_error(rc, err, "no checkpoint")
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == before


def _next_checkpoint(tmp_path, n_j=6):
    from calibration.next.checkpoint import NextCheckpoint, save_checkpoint
    from calibration.next.data import Normalizer
    from calibration.next.model import ModelConfig, NextModel

    torch.manual_seed(0)
    m = NextModel(
        ModelConfig(n_in=3 * n_j, n_out=n_j, history=10, arch="lstm", hidden=16, head_hidden=16)
    ).eval()
    norm = Normalizer(np.zeros(3 * n_j), np.ones(3 * n_j), np.zeros(n_j), np.full(n_j, 0.01))
    ck = NextCheckpoint(
        model=m,
        normalizer=norm,
        arm="",
        joint_names=[f"joint{i + 1}" for i in range(n_j)],
        units="N*m",
        inputs="q,qd,dq",
        rate_hz=100.0,
        x_min=np.full(3 * n_j, -3.0),
        x_max=np.full(3 * n_j, 3.0),
        metrics={"val_l1": [0.05] * n_j},
    )
    return save_checkpoint(ck, tmp_path / "next")


def test_next_offline_labels_from_the_logged_joint_states(tmp_path, capsys):
    from calibration.next.estimator import batch_tau_f
    from calibration.next.ident import NextId
    from policies.data.recordings import load_episodes
    from policies.labels.labelling import ThresholdSource, episode_tau_ext, load_next, resolve_thresholds

    write_recording(tmp_path / "a.mcap", episodes=1, seconds=2.0, cameras=(), tau_ext=False)
    ck_path = _next_checkpoint(tmp_path)
    eps, arms = load_episodes([tmp_path])
    model = load_next(ck_path)
    t, tau, source = episode_tau_ext(eps[0], arms, model)
    assert "offline" in source and np.isnan(tau[:9]).all() and np.isfinite(tau[9:]).all()
    log = eps[0].to_plain("follower")
    expect = log.tau - batch_tau_f(model.ck, log.q, log.qd, log.q_cmd)  # the log is uniform at 100 Hz already
    np.testing.assert_allclose(tau[9:], expect[9 : len(tau)], atol=1e-5)
    # the pass is kept by the model that made it (no process-wide memo): the same arrays again, a fresh model
    # starts empty
    assert episode_tau_ext(eps[0], arms, model)[1] is tau and len(model.offline_runs) == 1
    assert load_next(ck_path).offline_runs == {}
    th = resolve_thresholds("next", model, eps, arms)
    assert th.t_low == pytest.approx(2.0 * 0.3) and th.t_high == pytest.approx(3.0 * 0.3)
    assert resolve_thresholds(None, model, eps, arms) == th  # the library's former default stays
    rec = resolve_thresholds("recording", model, eps, arms)
    assert rec.source.kind is ThresholdSource.RECORDING and str(rec.source).startswith("recording: Otsu")
    assert th.source.kind is ThresholdSource.NEXT and th.source.get("next_id") == NextId.of(ck_path)
    rc = main(["episodes", "phases", str(tmp_path), "--next", str(ck_path), "--thresholds", "next",
               "--out", str(tmp_path / "ph")])
    out = capsys.readouterr().out
    assert rc == 0 and "NEXT next@" in out and len(list((tmp_path / "ph").glob("*.png"))) == 1


def test_thresholds_next_from_the_checkpoint_the_session_names(tmp_path):
    from policies.data.recordings import load_episodes
    from policies.labels.labelling import resolve_thresholds

    ck_path = _next_checkpoint(tmp_path)
    write_recording(
        tmp_path / "a.mcap",
        episodes=1,
        seconds=1.0,
        cameras=(),
        metadata={"next_checkpoint": f"{ck_path}#0123abcd"},
    )
    eps, arms = load_episodes([tmp_path])
    th = resolve_thresholds("next", None, eps, arms)
    assert (th.t_low, th.t_high) == (pytest.approx(0.6), pytest.approx(0.9)) and "next@" in str(th.source)


def test_normaliser_clips_tiny_spreads_and_centres_constants():
    from policies.data.normalizer import STD_MIN, Normalizer

    rng = np.random.default_rng(0)
    x = np.stack([rng.normal(0, 0.3, 500), rng.normal(0.1, 0.003, 500), np.full(500, 0.02)], 1)
    n = Normalizer.fit({"state": x})
    assert n.std["state"][0] == pytest.approx(0.3, rel=0.1)
    assert n.std["state"][1] == pytest.approx(STD_MIN)  # barely moves: clipped, not amplified 100x
    assert n.std["state"][2] == 1.0  # constant: centred only
    z = n.norm("state", np.array([[0.0, 0.15, 0.02]]))
    assert abs(z[0, 1]) < 6 and z[0, 2] == 0.0
