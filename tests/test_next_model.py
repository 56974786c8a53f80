"""NEXT model, training loop (early stopping), checkpoint round trip and refusal."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from calibration.next.checkpoint import NextCheckpoint, load_checkpoint, save_checkpoint
from calibration.next.data import Segment, build_windows
from calibration.next.model import ModelConfig, NextModel
from calibration.next.train import EarlyStopping, TrainConfig, lr_at, stopped_paying, train
from hardware.errors import UserError

torch.set_num_threads(1)


@pytest.mark.parametrize("arch", ["lstm", "gru", "mlp"])
def test_model_shapes(arch):
    m = NextModel(ModelConfig(n_in=9, n_out=3, history=10, arch=arch, hidden=16, head_hidden=16))
    assert m(torch.zeros(5, 10, 9)).shape == (5, 3)


def test_early_stopping_logic():
    es = EarlyStopping(patience=3, warmup=5, min_delta=0.1)
    stops = [es.step(e, loss)[1] for e, loss in enumerate([1.0, 2, 2, 2, 2, 2, 2, 2])]
    # no stop during warm-up even though epochs 1..4 did not improve; stop once 3 bad epochs after warm-up
    assert stops == [False] * 7 + [True]
    es = EarlyStopping(patience=2, warmup=0, min_delta=0.1)
    assert es.step(0, 1.0) == (True, False)
    assert es.step(1, 0.95) == (False, False)  # within min_delta: not an improvement
    assert es.step(2, 0.5) == (True, False)
    assert es.best == 0.5 and es.best_epoch == 2


def _synthetic_segments(n=4000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    q = np.stack([np.sin(0.7 * t + p) for p in (0.0, 1.0)], 1)
    qd = np.stack([0.7 * np.cos(0.7 * t + p) for p in (0.0, 1.0)], 1)
    tau = 2.0 * np.sin(q) + 0.5 * np.tanh(qd / 0.1) + 0.01 * rng.normal(size=q.shape)
    return [Segment(t=t, q=q, qd=qd, q_cmd=q + 0.01 * qd, tau=tau, rate_hz=100.0)]


def _small_cfg(**kw):
    base = dict(history=10, hidden=16, head_hidden=32, lr=3e-3, batch_size=128, samples_per_epoch=1024,
                max_epochs=8, patience=5, warmup=3, threads=1)
    base.update(kw)
    return TrainConfig(**base)


def test_training_reduces_error_and_calls_back():
    data = build_windows(_synthetic_segments(), history=10, block_s=5.0)
    seen = []
    res = train(data, _small_cfg(), callback=lambda p: seen.append(p.val_loss), progress_bar=False)
    assert seen and res.epochs == len(seen)
    assert min(seen) < 0.5 * seen[0]
    assert res.best_val_loss == pytest.approx(min(seen), rel=1e-6) or res.best_val_loss <= min(seen)
    assert len(res.val_l1) == 2 and res.device == "cpu"
    assert len(res.carried_max_diff) == 2 and all(0.0 <= d < np.inf for d in res.carried_max_diff)
    stopped = train(data, _small_cfg(max_epochs=10), callback=lambda p: p.epoch >= 1, progress_bar=False)
    assert stopped.epochs == 2


def test_checkpoint_round_trip_and_refusal(tmp_path):
    data = build_windows(_synthetic_segments(1500), history=10, block_s=5.0)
    res = train(data, _small_cfg(max_epochs=2), progress_bar=False)
    ck = NextCheckpoint(model=res.model, normalizer=data.normalizer, arm="piper", joint_names=["j1", "j2"],
                        units="N*m", inputs="q,qd,dq", rate_hz=100.0, x_min=data.x_min, x_max=data.x_max,
                        data_hash=data.data_hash, train_config=res.config.to_dict(), metrics={"x": 1})
    path = save_checkpoint(ck, tmp_path / "next")
    assert (tmp_path / "next.safetensors").exists() and path.suffix == ".json"
    ck2 = load_checkpoint(tmp_path / "next", arm="piper", joint_names=["j1", "j2"])
    x = torch.randn(3, 10, 6)
    with torch.no_grad():
        assert torch.allclose(ck.model(x), ck2.model(x))
    assert np.allclose(ck2.normalizer.y_std, data.normalizer.y_std) and ck2.data_hash == data.data_hash
    with pytest.raises(UserError, match="arm"):
        load_checkpoint(tmp_path / "next.json", arm="yam")
    with pytest.raises(UserError, match="joints"):
        load_checkpoint(tmp_path / "next", joint_names=["j1", "j3"])
    with pytest.raises(UserError, match="not found"):
        load_checkpoint(tmp_path / "missing")
    (tmp_path / "bad.json").write_text("{not json")
    (tmp_path / "bad.safetensors").write_bytes(b"xx")
    with pytest.raises(UserError, match="not a readable"):
        load_checkpoint(tmp_path / "bad")


def test_lr_schedule_warmup_cosine_floor():
    cfg = TrainConfig(lr=1e-3, lr_peak=5e-3, lr_warmup_windows=100, lr_decay_windows=200, lr_final=1e-4)
    assert lr_at(cfg, 0) == pytest.approx(1e-3) and lr_at(cfg, 50) == pytest.approx(3e-3)
    assert lr_at(cfg, 100) == pytest.approx(5e-3) and lr_at(cfg, 200) == pytest.approx(0.5 * (5e-3 + 1e-4))
    assert lr_at(cfg, 300) == pytest.approx(1e-4) and lr_at(cfg, 10**6) == pytest.approx(1e-4)
    flat = TrainConfig(lr=1e-3, lr_peak=1e-3, lr_warmup_windows=0, lr_decay_windows=0)
    assert lr_at(flat, 0) == lr_at(flat, 10**6) == pytest.approx(1e-3)


def test_lr_schedule_follows_the_wall_budget_when_it_is_further():
    cfg = TrainConfig(lr=1e-3, lr_peak=5e-3, lr_warmup_windows=100, lr_decay_windows=200, lr_final=1e-4,
                      max_seconds=10.0)
    assert lr_at(cfg, 0, 0.0) == pytest.approx(1e-3)
    assert lr_at(cfg, 0, 9.0) == pytest.approx(1e-4)  # 90 % of the budget spent: annealed, whatever was seen
    assert lr_at(cfg, 100, 1.0) == pytest.approx(5e-3)  # windows further than time: windows rule


def test_validation_gain_rule_stops_when_the_loss_stops_paying():
    # best validation loss per epoch; rule: < 1 % gain over the last 3 epochs, never before epoch 4
    assert not stopped_paying([1.0, 0.5, 0.4, 0.3], 0.01, 3, 4)
    assert not stopped_paying([1.0, 0.5, 0.4, 0.3, 0.25], 0.01, 3, 4)
    assert stopped_paying([1.0, 0.5, 0.4, 0.3, 0.2999, 0.2998, 0.2997], 0.01, 3, 4)
    assert not stopped_paying([1.0, 1.0, 1.0, 1.0, 1.0], 0.01, 0, 0)  # rule off
    data = build_windows(_synthetic_segments(), history=10, block_s=5.0)
    res = train(data, _small_cfg(max_epochs=200, patience=1000, warmup=2, min_gain=0.5, gain_epochs=2),
                progress_bar=False)
    assert res.stop_reason == "validation gain" and res.epochs < 200
    assert res.seconds_to_within_5pct is not None and res.seconds_to_within_5pct <= res.seconds
    timed = train(data, _small_cfg(max_epochs=10**6, patience=10**6, gain_epochs=0, max_seconds=1.0),
                  progress_bar=False)
    assert timed.stop_reason == "budget" and timed.seconds < 3.0


def test_thread_probe_keeps_the_faster_and_drops_to_one_thread_on_a_collapse():
    from calibration.next.train import ThreadProbe

    now = [0.0]  # the batches' durations are given, not slept: a busy or slow machine oversleeps (#53)
    probe = ThreadProbe(cores=2, clock=lambda: now[0])
    try:
        for batch, took in ((0, 0.0), (1, 0.005), (2, 0.15), (3, 0.0)):  # probe: 2 threads faster
            probe.before(0, batch)
            now[0] += took
            probe.after()
        assert probe.threads == 2
        probe.before(0, 4)
        now[0] += 0.4  # far over its probe: the machine got busy
        probe.after()
        assert probe.threads == 1 and torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(1)
