"""bench/force_history.py's pieces: the history windows, the ROC area and the logistic fit."""
import numpy as np

from bench.force_history import balanced_accuracy, best_threshold, fit_logistic, roc_auc, score, windows


def test_roc_auc_matches_the_pairwise_definition():
    rng = np.random.default_rng(1)
    y = (rng.random(600) < 0.3).astype(float)
    s = np.round(rng.normal(size=600) + 1.5 * y, 1)  # ties included
    pos, neg = s[y == 1], s[y == 0]
    brute = np.mean((pos[:, None] > neg[None, :]) + 0.5 * (pos[:, None] == neg[None, :]))
    assert np.isclose(roc_auc(s, y), brute)
    assert np.isnan(roc_auc(s, np.zeros_like(y)))


def test_windows_hold_the_past_only():
    x = np.arange(5.0)[:, None] * np.array([[1.0, -1.0]])
    w = windows(x, 3)
    assert w.shape == (5, 12)
    # per step back: tau, then |tau|
    assert np.allclose(w[3], [3, -3, 3, 3, 2, -2, 2, 2, 1, -1, 1, 1])
    assert np.allclose(w[0], 0)  # before the start: sample 0 repeated


def test_a_history_separates_what_one_step_cannot():
    # contact shows only as a change from the step before: each step alone has the same distribution
    rng = np.random.default_rng(0)
    n = 3000
    y = (rng.random(n) < 0.5).astype(float)
    now = rng.normal(size=n)
    before = now + 1.5 * y + 0.1 * rng.normal(size=n)
    x = np.stack([before, now], axis=1).reshape(-1, 1)  # before_0, now_0, before_1, now_1, ...
    aucs = {}
    for h in (1, 2):
        f = windows(x, h)[1::2]  # at the "now" samples
        mu, sd = f.mean(0), f.std(0) + 1e-9
        aucs[h] = roc_auc(score((f - mu) / sd, fit_logistic((f - mu) / sd, y)), y)
    assert aucs[1] < 0.6 and aucs[2] > 0.97
    z = np.r_[np.zeros(50), np.ones(50)]
    assert balanced_accuracy(z, z, best_threshold(z, z)) == 1.0
