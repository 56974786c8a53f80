"""NEXT data pipeline: resampling, inputs, normalisation, contiguous-block split without leakage."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.next.data import (
    Normalizer,
    build_windows,
    gather_windows,
    make_inputs,
    n_inputs,
    resample_log,
    split_blocks,
    window_ends,
)
from hardware.recording.plain_log import PlainLog


def _log(n=500, gap_at=None, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.006, 0.010, n))
    if gap_at is not None:
        t[gap_at:] += 1.0
    q = np.sin(t[:, None] + np.arange(3))
    return PlainLog(path=__import__("pathlib").Path("x.npz"), t=t, q=q, qd=np.cos(t[:, None] + np.arange(3)),
                    q_cmd=q + 0.01, tau=rng.normal(size=(n, 3)), units="A", joint_names=["a", "b", "c"])


def test_resample_uniform_and_split_at_gaps():
    segs = resample_log(_log(gap_at=200), rate_hz=100.0)
    assert len(segs) == 2
    for s in segs:
        assert np.allclose(np.diff(s.t), 0.01)
        assert s.q.shape == (len(s), 3)


def test_inputs_shapes():
    q = np.zeros((7, 4))
    for inputs, mult in (("q", 1), ("q,qd", 2), ("q,qd,dq", 3)):
        assert make_inputs(q, q, q + 1, inputs).shape == (7, 4 * mult) == (7, n_inputs(4, inputs))
    assert np.all(make_inputs(q, q, q + 1, "q,qd,dq")[:, 8:] == 1)
    with pytest.raises(ValueError):
        make_inputs(q, q, q, "bad")


def test_normalizer_round_trip():
    rng = np.random.default_rng(1)
    x, y = rng.normal(3, 2, (100, 5)), rng.normal(-1, 4, (100, 2))
    n = Normalizer.fit(x, y)
    n2 = Normalizer.from_dict(n.to_dict())
    assert np.allclose(n2.norm_x(x).mean(0), 0, atol=1e-9) and np.allclose(n2.norm_x(x).std(0), 1)
    assert np.allclose(n2.denorm_y(n2.norm_y(y)), y)


def test_block_split_has_no_leakage():
    lengths = [1000, 730, 90]
    train, val = split_blocks(lengths, block_len=100, val_every=5)
    assert train and val
    offsets = list(np.r_[0, np.cumsum(lengths)[:-1]])
    h = 20
    tr = window_ends(train, offsets, h)
    va = window_ends(val, offsets, h)
    tr_samples = set((tr[:, None] + np.arange(-h + 1, 1)).ravel().tolist())
    va_samples = set((va[:, None] + np.arange(-h + 1, 1)).ravel().tolist())
    assert not tr_samples & va_samples
    # windows never cross a segment boundary
    for ends in (tr, va):
        seg_of = np.searchsorted(np.cumsum(lengths), ends, side="right")
        seg_of_start = np.searchsorted(np.cumsum(lengths), ends - h + 1, side="right")
        assert np.all(seg_of == seg_of_start)
    # validation blocks are contiguous stretches, not scattered samples
    assert all(hi - lo >= 50 for _, lo, hi in val)


def test_build_windows_normalised_on_train_only():
    segs = resample_log(_log(n=3000), 100.0)
    wd = build_windows(segs, history=10, inputs="q,qd,dq", block_s=2.0)
    assert wd.x.shape[1] == 9 and wd.y.shape[1] == 3 and wd.x.dtype == np.float32
    assert len(wd.train_ends) > len(wd.val_ends) > 0
    w = gather_windows(wd.x, wd.train_ends[:4], 10)
    assert w.shape == (4, 10, 9)
    assert np.all(wd.x_min <= wd.x_max)


def test_segments_carry_the_arm_their_log_names():
    from calibration.next.data import logged_arm

    log = _log()
    log.arm, log.arm_sha256 = "piper", "ab" * 32
    segs = resample_log(log, 100.0)
    assert segs[0].arm == "piper" and segs[0].joint_names == ("a", "b", "c") and segs[0].units == "A"
    assert logged_arm(segs) == "piper"  # calibrate --from-logs needs no --arm for such logs
    assert logged_arm(segs + resample_log(_log(seed=1), 100.0)) is None  # one log names none: unknown
