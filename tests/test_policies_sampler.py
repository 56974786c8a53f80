"""FIRST sampler: phase frequencies, determinism, disjoint DDP shards, ratio parsing."""

from __future__ import annotations

import numpy as np
import pytest

from policies.data import sampler as S


def _phases(seed=0, n=5000):
    rng = np.random.default_rng(seed)
    return rng.choice(3, size=n, p=[0.7, 0.1, 0.2]).astype(np.int8)


@pytest.mark.parametrize("ratio", ["1:5:1", "C", "PC+C", "uniform", "2:0:1"])
def test_phase_frequencies_match_expected_share_over_1e5_draws(ratio):
    ph = _phases()
    w = S.parse_ratio(ratio)
    sampler = S.FirstSampler(ph, w, seed=3, samples_per_epoch=100_000)
    drawn = ph[sampler.epoch_indices(0)]
    freq = np.bincount(drawn, minlength=3) / len(drawn)
    expected = S.expected_shares(ph, w)
    assert np.all(np.abs(freq - expected) < 0.01), (freq, expected)
    if w[1] == 0:
        assert freq[1] == 0


def test_draws_are_deterministic_per_seed_and_epoch():
    ph = _phases()
    a = S.FirstSampler(ph, seed=1).epoch_indices(2)
    assert np.array_equal(a, S.FirstSampler(ph, seed=1).epoch_indices(2))
    assert not np.array_equal(a, S.FirstSampler(ph, seed=1).epoch_indices(3))
    assert not np.array_equal(a, S.FirstSampler(ph, seed=2).epoch_indices(2))


def test_ddp_shards_are_disjoint_and_cover_the_global_batch():
    ph = _phases()
    world, batch = 4, 64
    one = S.FirstSampler(ph, seed=5)
    ranks = [S.FirstSampler(ph, seed=5, rank=r, world=world) for r in range(world)]
    for step in range(3):
        g_idx, g_pos = one.batch(1, step, batch)
        got = [r.batch(1, step, batch) for r in ranks]
        positions = np.concatenate([p for _, p in got])
        assert len(set(positions.tolist())) == batch  # no position drawn by two ranks
        assert sorted(positions.tolist()) == list(range(batch))
        merged = np.empty(batch, dtype=g_idx.dtype)
        for idx, pos in got:
            merged[pos] = idx
        assert np.array_equal(merged, g_idx)
    epoch = np.concatenate([r.epoch_indices(1) for r in ranks])
    assert np.array_equal(np.sort(epoch), np.sort(one.epoch_indices(1)))


@pytest.mark.parametrize("bad", ["1:5", "1:-1:1", "0:0:0", "a:b:c", "1:nan:1", ""])
def test_bad_ratios_are_refused(bad):
    with pytest.raises(ValueError, match="non-negative"):
        S.parse_ratio(bad)


def test_ratio_zeroing_every_present_phase_is_refused():
    with pytest.raises(ValueError, match="zero weight"):
        S.FirstSampler(np.zeros(10, np.int8), (0.0, 1.0, 1.0))


def test_a_batch_larger_than_the_data_repeats_samples():
    # 60 samples, global batch 256 (the state preset's default): one full batch of draws with replacement
    s = S.FirstSampler(np.zeros(60, np.int64), seed=1)
    assert s.steps_per_epoch(256) == 1
    idx, pos = s.batch(0, 0, 256)
    assert len(idx) == 256 and (idx < 60).all() and (pos == np.arange(256)).all()
    assert (s.batch(0, 0, 256)[0] == idx).all()  # deterministic
    short = S.FirstSampler(np.zeros(600, np.int64), seed=1)
    assert (short.batch(0, 0, 256)[0] == short.global_indices(0)[:256]).all()  # normal epochs unchanged
