"""NEXT calibration on the logs real arms produce (issue 23, item 5): one test per defect, synthetic logs
built here (a 2-joint arm driven by sines; torque = gravity-like + friction, in A or N*m), tiny training."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from calibration.next.data import resample_log
from calibration.next.logs import clean_rows, increasing_rows, read_logs
from calibration.next.train import TrainConfig
from calibration.report import calibrate_from_logs
from factr2_teleop.cli import main

torch.set_num_threads(1)
TINY = dict(history=10, hidden=8, head_hidden=16, batch_size=128, samples_per_epoch=256, max_epochs=2,
            threads=1, device="cpu")


def _motion(t: np.ndarray, seed: int = 0):
    """q [rad], qd [rad/s], torque signal of a 2-joint arm at times t [s]."""
    rng = np.random.default_rng(seed)
    f, ph = rng.uniform(0.2, 0.5, 2), rng.uniform(0, 6, 2)
    q = 0.8 * np.sin(2 * np.pi * f * t[:, None] + ph)
    qd = 0.8 * 2 * np.pi * f * np.cos(2 * np.pi * f * t[:, None] + ph)
    outer = 0.5 * np.sin(q[:, 0] + q[:, 1])
    tau = np.stack([2.0 * np.sin(q[:, 0]) + outer, outer], 1)
    return q, qd, tau + 0.3 * np.tanh(qd / 0.05)


def _save(path, t, seed=0, q_cmd=True, torque="current", **extra):
    q, qd, tau = _motion(t, seed)
    arrays = dict(t=t, q=q, qd=qd, **{torque: tau}, joint_names=np.array(["j1", "j2"]), **extra)
    if q_cmd:
        arrays["q_cmd"] = q + 0.02 * qd
    np.savez(path, **arrays)
    return path


def _uniform(seconds, rate_hz=100.0):
    return np.arange(int(seconds * rate_hz)) / rate_hz


def test_no_q_cmd_falls_back_to_q_qd_and_says_so(tmp_path):
    """A velocity-controlled arm logs no commanded position: trained on (q, q_dot), in the report and
    printed, instead of `missing array(s): q_cmd`."""
    train = [_save(tmp_path / f"run{i}.npz", _uniform(30), seed=i, q_cmd=False) for i in range(2)]
    held = _save(tmp_path / "held.npz", _uniform(15), seed=5, q_cmd=False)
    said = []
    rep = calibrate_from_logs(train, tmp_path / "cal", [held], cfg=TrainConfig(**TINY), plots=False,
                              say=said.append)
    assert rep["inputs"] == "q,qd" and "q_cmd" in rep["inputs_fallback"]
    assert any("q_cmd" in s for s in said)
    assert "no q_cmd" in " ".join(rep["log_notes"]["run0"])
    assert np.isfinite(rep["methods"]["next"]["free_l1_mean"])
    assert np.isfinite(rep["methods"]["ridge"]["free_l1_mean"])
    ck = json.loads((tmp_path / "cal" / "next.json").read_text())
    assert ck["inputs"] == "q,qd" and ck["model"]["n_in"] == 4


def test_irregular_sample_times_are_resampled_onto_one_grid(tmp_path):
    """2-30 ms steps at ~100 Hz: one uniform 100 Hz segment (no step is a gap), values interpolated."""
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.002, 0.030, 3000))
    [r] = read_logs(_save(tmp_path / "jitter.npz", t))
    assert any("irregular clock" in n and "resampled to 100 Hz" in n for n in r.notes)
    [seg] = resample_log(r.log, 100.0)
    assert np.allclose(np.diff(seg.t), 0.01)
    q_true, _, _ = _motion(seg.t)
    assert np.max(np.abs(seg.q - q_true)) < 2e-3  # linear interpolation over <= 30 ms of a slow sine


def test_corrupt_rows_are_dropped_with_a_warning_saying_how_many_and_where(tmp_path):
    t = _uniform(20)
    q, qd, tau = _motion(t)
    q[100, 1] = np.nan  # a NaN value
    tau[200:203, 0] = np.inf  # three rows of inf
    t_bad = t.copy()
    t_bad[500] = 1e6  # one wild timestamp: costs that row only, not the rest of the log
    t_bad[900:905] = t_bad[880:885]  # the clock jumps back for 5 rows
    np.savez(tmp_path / "bad.npz", t=t_bad, q=q, qd=qd, q_cmd=q, current=tau)
    [r] = read_logs(tmp_path / "bad.npz")
    note = " ".join(r.notes)
    assert r.dropped == 1 + 3 + 1 + 5
    assert "dropped 10 corrupt row(s) of 2000" in note
    assert "4 with NaN/inf values at rows 100 (t 1.00 s), 200-202 (t 2.00 s)" in note
    assert "6 with time out of order at rows 500" in note
    assert np.all(np.diff(r.log.t) > 0) and len(r.log.t) == 1990
    assert np.all(np.isfinite(r.log.q)) and np.all(np.isfinite(r.log.tau))
    # the rule on its own: the longest increasing run of times, non-finite never kept
    assert increasing_rows(np.array([0.0, 1.0, 9.0, 2.0, 3.0, np.nan, 4.0])).tolist() == [
        True, True, False, True, True, False, True]
    keep, msg = clean_rows(np.arange(5.0), {"q": np.zeros((5, 2))})
    assert keep.all() and msg == ""


def test_current_without_torque_constant_is_trained_and_reported_in_amperes(tmp_path, capsys):
    train = _save(tmp_path / "cur.npz", _uniform(40))
    out = tmp_path / "cal"
    code = main(["calibrate", "--from-logs", str(train), "--out", str(out), "--max-epochs", "2",
                 "--history", "10", "--max-seconds", "5", "--no-plots"])
    assert code == 0
    err = capsys.readouterr().err
    assert "current without a torque constant: trained and scored in A" in err
    assert "estimates in A" in err and "[A]" in err
    rep = json.loads((out / "report.json").read_text())
    assert rep["units"] == "A" and rep["prior"] == "data-only"  # no arm description: the data-only grey box
    # with a torque constant the same log is in N*m
    k = _save(tmp_path / "nm.npz", _uniform(5), torque_constant=np.array([2.0, 3.0]))
    [r] = read_logs(k)
    assert r.log.units == "N*m" and not any("in A" in n for n in r.notes)


def test_logs_of_different_lengths_and_rates_train_together(tmp_path):
    """125 Hz, 50 Hz and a log shorter than one window: all on the one 100 Hz grid, trained together."""
    logs = [_save(tmp_path / "fast.npz", _uniform(30, 125.0), seed=1),
            _save(tmp_path / "slow.npz", _uniform(30, 50.0), seed=2),
            _save(tmp_path / "short.npz", _uniform(0.05, 125.0), seed=3)]
    reads = [r for p in logs for r in read_logs(p)]
    assert [len(r.log.t) for r in reads] == [3750, 1500, 6]
    segs = [s for r in reads for s in resample_log(r.log, 100.0)]
    assert all(np.allclose(np.diff(s.t), 0.01) for s in segs)
    assert [len(s) for s in segs] == [3000, 2999, 5]
    rep = calibrate_from_logs(logs, tmp_path / "cal", cfg=TrainConfig(**TINY), plots=False)
    assert rep["train_logs"] == ["fast", "slow", "short"]
    assert rep["data_minutes"] == pytest.approx(6004 / 100 / 60)
    assert np.isfinite(rep["methods"]["next"]["free_l1_mean"])
