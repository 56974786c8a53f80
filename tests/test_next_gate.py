"""The gate on NEXT's learned correction (issue 23): fitted on whole held-out runs, stored in the checkpoint,
applied by the batch model and the streaming estimator; single-run logs keep block validation, no gate."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from calibration.next.checkpoint import NextCheckpoint, load_checkpoint, save_checkpoint
from calibration.next.data import Normalizer, Segment, build_windows, split_runs, validation_split
from calibration.next.estimator import NextEstimator, batch_tau_f
from calibration.next.gate import crossfit_folds, fit_gate, gate_offset
from calibration.next.model import ModelConfig, NextModel
from calibration.next.train import TrainConfig, predict_windows, train

torch.set_num_threads(1)


def test_gate_is_zero_for_noise_one_for_the_truth_and_the_scale_in_between():
    rng = np.random.default_rng(0)
    r = rng.normal(size=(20000, 4))  # the residual the prior leaves
    noise = rng.normal(size=r.shape)  # a correction unrelated to it
    c = np.column_stack([noise[:, 0], r[:, 1], 2.0 * r[:, 2], -r[:, 3]])
    a = fit_gate(c, r)
    assert abs(a[0]) < 0.03  # pure noise: the network is switched off on that joint
    assert a[1] == pytest.approx(1.0)  # the right correction is kept whole
    assert a[2] == pytest.approx(0.5)  # twice too large: halved
    assert a[3] == 0.0  # the wrong sign: clipped to 0, never negative


def test_gate_clips_above_one_ignores_bad_rows_and_keeps_a_silent_network():
    r = np.column_stack([np.linspace(-1, 1, 100), np.linspace(-1, 1, 100)])
    c = np.column_stack([0.5 * r[:, 0], np.zeros(100)])  # joint 1: the network says nothing
    c[3, 0] = np.nan
    a = fit_gate(c, r)
    assert a[0] == 1.0 and a[1] == 1.0
    with pytest.raises(ValueError):
        fit_gate(c[:, :1], r)


def test_gate_offset_makes_the_gate_act_on_the_correction_in_data_units():
    alpha, y_mean, y_std = np.array([0.0, 0.5, 1.0]), np.array([2.0, -1.0, 3.0]), np.array([0.5, 2.0, 1.0])
    out = np.array([0.3, -0.7, 1.1])  # normalised network output
    gated = (alpha * out + gate_offset(alpha, y_mean, y_std)) * y_std + y_mean
    np.testing.assert_allclose(gated, alpha * (out * y_std + y_mean))


def test_split_runs_holds_out_whole_runs_only_with_three_or_more():
    assert split_runs(["a", "a", "b"], [10, 20, 30]) is None  # two runs: blocks validate
    names = ["r0", "r1", "r2", "r3", "r3", "r4", "r5"]  # r3 cut in two segments (a gap)
    train_b, val_b = split_runs(names, [100] * 7)
    assert val_b == [(3, 0, 100), (4, 0, 100)]  # run 3 = (3 + 2) % 5 == 0, all of its segments
    assert [i for i, _, _ in train_b] == [0, 1, 2, 5, 6]
    _, val3 = split_runs(["x", "y", "z"], [50, 60, 70])  # the rule picks none: the last run
    assert val3 == [(2, 0, 70)]


def _runs(names, n=1500, seed=0):
    """Segments of a 2-joint arm, one per name, each a different trajectory."""
    rng = np.random.default_rng(seed)
    segs = []
    for k, name in enumerate(names):
        t = np.arange(n) / 100.0
        q = np.stack([np.sin((0.5 + 0.2 * k) * t + p) for p in (0.0, 1.0 + k)], 1)
        qd = np.gradient(q, t, axis=0)
        tau = 2.0 * np.sin(q) + 0.5 * np.tanh(qd / 0.1) + 0.01 * rng.normal(size=q.shape)
        segs.append(Segment(t=t, q=q, qd=qd, q_cmd=q + 0.01 * qd, tau=tau, rate_hz=100.0, name=name))
    return segs


def _cfg(**kw):
    base = dict(history=10, hidden=16, head_hidden=32, lr=3e-3, batch_size=128, samples_per_epoch=1024,
                max_epochs=4, patience=5, warmup=2, threads=1, max_seconds=float("inf"))
    return TrainConfig(**{**base, **kw})


def test_heldout_gate_validates_on_a_whole_run_and_fits_alpha_there():
    data = build_windows(_runs(["a", "b", "c"]), history=10, block_s=5.0)
    assert data.val_runs == ["c"]
    tr, val, used = validation_split(data, "auto")
    assert used == "runs" and tr.max() < val.min()  # c comes last: every validation window is c's
    res = train(data, _cfg(validation="runs", gate="heldout"), progress_bar=False)
    assert res.validation == "runs" and res.val_runs == ["c"]
    assert res.gate is not None and len(res.gate) == 2 and all(0.0 <= g <= 1.0 for g in res.gate)
    assert res.model.cfg.gate == res.gate  # in the config: saved in the checkpoint's JSON
    # the gate is the clipped least-squares scale of the ungated correction on the held-out run
    x = torch.as_tensor(data.x)
    gated = predict_windows(res.model, x, val, 10).numpy()
    res.model.set_gate(None, None)
    raw = predict_windows(res.model, x, val, 10).numpy()
    ym, ys = data.normalizer.y_mean, data.normalizer.y_std
    np.testing.assert_allclose(res.gate, fit_gate(raw * ys + ym, data.y[val] * ys + ym), atol=1e-4)
    np.testing.assert_allclose(gated * ys + ym, np.asarray(res.gate) * (raw * ys + ym), atol=1e-4)
    off = train(data, _cfg(validation="runs", gate="none"), progress_bar=False)  # the switch for ablations
    assert off.validation == "runs" and off.gate is None and off.model.cfg.gate is None
    with pytest.raises(ValueError):
        train(data, _cfg(gate="yes"), progress_bar=False)


def test_crossfit_folds_score_every_run_once_as_unseen():
    data = build_windows(_runs(["a", "b", "c", "d"], n=600), history=10, block_s=2.0)
    folds = crossfit_folds(data.run_index, data.train_ends, data.val_ends, k=3)
    assert len(folds) == 3
    every = np.union1d(data.train_ends, data.val_ends)
    np.testing.assert_array_equal(np.sort(np.concatenate([h for _, _, h in folds])), every)
    for f, (tr, va, held) in enumerate(folds):
        held_runs = set(data.run_index[held])
        assert held_runs == {r for r in range(4) if r % 3 == f}  # runs 0 and 3 share fold 0
        assert not held_runs & set(data.run_index[tr]) and not held_runs & set(data.run_index[va])
        assert set(tr) <= set(data.train_ends) and set(va) <= set(data.val_ends)  # the blocks' split
    assert crossfit_folds(data.run_index[data.run_index < 2], data.train_ends[:5], data.val_ends[:5]) == []


@pytest.mark.parametrize("learnable", [True, False])
def test_crossfit_gate_keeps_a_correction_that_transfers_and_drops_one_that_does_not(learnable):
    """Residual = a function of q shared by every run (the network's correction transfers: alpha high),
    or white noise (nothing to transfer: alpha low). The final model validates on blocks."""
    segs = _runs(["a", "b", "c", "d", "e", "f"], n=1200)
    rng = np.random.default_rng(5)
    for s in segs:
        s.tau = 2.0 * np.sin(s.q) + 0.01 * rng.normal(size=s.q.shape) if learnable else \
            rng.normal(0, 0.5, s.q.shape)
    data = build_windows(segs, history=10, block_s=4.0)
    res = train(data, _cfg(max_epochs=6), progress_bar=False)
    assert res.validation == "blocks" and res.gate is not None and res.model.cfg.gate == res.gate
    if learnable:
        assert min(res.gate) > 0.8
    else:
        assert max(res.gate) < 0.3


def _gated_ck(arch="lstm", n_j=3, history=12):
    torch.manual_seed(0)
    m = NextModel(ModelConfig(n_in=3 * n_j, n_out=n_j, history=history, arch=arch, hidden=24, head_hidden=32))
    rng = np.random.default_rng(0)
    norm = Normalizer(rng.normal(size=3 * n_j), rng.uniform(0.5, 2, 3 * n_j), rng.normal(size=n_j),
                      rng.uniform(0.5, 2, n_j))
    alpha = np.array([0.0, 0.4, 1.0])
    m.set_gate(alpha.tolist(), gate_offset(alpha, norm.y_mean, norm.y_std).tolist())
    m.eval()
    return NextCheckpoint(model=m, normalizer=norm, arm="test", joint_names=[f"j{i}" for i in range(n_j)],
                          units="N*m", inputs="q,qd,dq", rate_hz=100.0, x_min=np.full(3 * n_j, -3.0),
                          x_max=np.full(3 * n_j, 3.0), metrics={"val_l1": [1.0] * n_j,
                                                                 "carried_max_diff": [0.0] * n_j})


@pytest.mark.parametrize("arch,carried", [("lstm", False), ("lstm", True), ("gru", None)])
def test_estimator_applies_the_gate(tmp_path, arch, carried):
    ck = load_checkpoint(save_checkpoint(_gated_ck(arch), tmp_path / "next"))  # through the JSON
    assert ck.model.cfg.gate == [0.0, 0.4, 1.0]
    rng = np.random.default_rng(1)
    n = 60
    q = np.cumsum(rng.normal(0, 0.05, (n, 3)), 0)
    qd, qc, tau = rng.normal(0, 0.5, (n, 3)), q + rng.normal(0, 0.01, (n, 3)), rng.normal(size=(n, 3))
    ref = batch_tau_f(ck, q, qd, qc)
    ungated = NextModel(ModelConfig(**{**ck.model.cfg.to_dict(), "gate": None, "gate_offset": None}))
    ungated.load_state_dict(ck.model.state_dict())
    raw = batch_tau_f(NextCheckpoint(**{**ck.__dict__, "model": ungated.eval()}), q, qd, qc)
    np.testing.assert_allclose(ref[11:, 0], 0.0, atol=1e-6)  # alpha 0: no correction at all
    np.testing.assert_allclose(ref[11:, 1], 0.4 * raw[11:, 1], atol=1e-5)
    np.testing.assert_allclose(ref[11:, 2], raw[11:, 2], atol=1e-5)
    est = NextEstimator(ck, carried=carried, audit_tol=1e-3 if carried else None)
    outs = [est.update(q[i], qd[i], qc[i], tau[i]) for i in range(n)]
    # carried: its first output is an exact window; later ones follow this random (not fading) network
    # only approximately, except where the gate is 0
    for i in range(11, 12 if carried else n):
        np.testing.assert_allclose(outs[i].tau_f, ref[i], atol=1e-4)
    np.testing.assert_allclose([o.tau_f[0] for o in outs[11:]], 0.0, atol=1e-6)
