"""hardware/timeseries.py: the one joint time-series type, resampler and held-out splitter that
calibration (NEXT), diagnosis and the recording reader share."""

from __future__ import annotations

import numpy as np

from hardware.timeseries import Segment, heldout_spans, hold_previous, interp_linear, resample, spans_mask


def test_resample_interpolates_floats_holds_bools_and_never_extrapolates():
    t = np.array([0.0, 0.1, 0.2, 0.4])
    y = np.array([[0.0, 1.0], [1.0, 1.0], [2.0, 0.0], [4.0, 0.0]])
    c = np.array([False, True, False, True])
    (grid, out), = resample(t, {"y": y, "contact": c, "none": None}, t_grid=np.array([-0.1, 0.05, 0.3, 0.5]))
    assert np.isnan(out["y"][0]).all() and np.isnan(out["y"][3]).all()  # outside the samples: NaN
    assert np.allclose(out["y"][1], [0.5, 1.0]) and np.allclose(out["y"][2], [3.0, 0.0])
    assert out["contact"].dtype == bool and out["contact"].tolist() == [False, False, False, True]
    assert out["none"] is None
    # inside the span, exactly numpy.interp per column (so NEXT's data did not change with the move)
    tg = np.linspace(0, 0.4, 17)
    assert np.array_equal(interp_linear(t, y, tg)[:, 0], np.interp(tg, t, y[:, 0]))
    assert hold_previous(t, np.arange(4), np.array([-1.0, 0.15]))[0] == 0  # before the first: 0 for ints


def test_resample_splits_at_gaps_with_a_grid_per_piece():
    t = np.r_[np.arange(0, 1.0, 0.007), 5.0 + np.arange(0, 1.0, 0.007)]
    q = np.sin(t)[:, None]
    pieces = resample(t, {"q": q}, rate_hz=100.0, max_gap_s=0.1)
    assert len(pieces) == 2
    for grid, out in pieces:
        assert np.allclose(np.diff(grid), 0.01) and np.allclose(out["q"][:, 0], np.sin(grid), atol=1e-4)
    assert pieces[1][0][0] == t[len(t) // 2]  # the second grid starts at its own first sample
    assert len(resample(t, {"q": q}, rate_hz=100.0)) == 1  # no max_gap_s: one piece, bridged


def test_tail_split_whole_trailing_series_or_the_tail_of_one():
    assert heldout_spans([1000], 0.25) == ([(0, 0, 750)], [(0, 750, 1000)])
    train, held = heldout_spans([500, 400, 1100], 0.25)
    assert train == [(0, 0, 500), (1, 0, 400)] and held == [(2, 0, 1100)]
    train, held = heldout_spans([900, 100, 100], 0.25)  # trailing series until a quarter is held out
    assert train == [(0, 0, 900)] and held == [(1, 0, 100), (2, 0, 100)]


def test_block_split_spreads_heldout_blocks_and_never_overlaps():
    lengths = [1000, 730, 90]
    train, held = heldout_spans(lengths, 1 / 5, block_len=100, offset=2, min_tail=50)
    assert held[:2] == [(0, 300, 400), (0, 800, 900)]
    assert (1, 600, 730) in train  # a short last block joins the one before it
    masks_t, masks_h = spans_mask(train, lengths), spans_mask(held, lengths)
    for mt, mh in zip(masks_t, masks_h):
        assert not np.any(mt & mh) and np.all(mt | mh)
    # the app's 20 s blocks (every 7th held out, the first trains) as a mask of one run
    (mask,) = spans_mask(heldout_spans([70_000], 0.15, block_len=2000)[1], [70_000])
    assert abs(mask.mean() - 1 / 7) < 0.01 and not mask[:2000].any() and mask[12_000:14_000].all()


def test_segment_slices_every_per_sample_array():
    n = 50
    s = Segment(t=np.arange(n) * 0.01, q=np.zeros((n, 2)), qd=np.ones((n, 2)), tau=np.ones((n, 2)),
                contact=np.zeros(n, bool), joint_names=("a", "b"), name="run", arm="piper")
    part = s.slice(10, 20)
    assert len(part) == 10 and part.contact.shape == (10,) and part.q_cmd is None
    assert part.name == "run" and part.arm == "piper" and part.n == 2 and part.t[0] == 0.1
    assert s.slice(0, 5, "head").name == "head" and s.source == "run"
