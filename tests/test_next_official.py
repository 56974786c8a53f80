"""The official NEXT stack's formats (calibration/next/h5_logs.py, official.py): its H5 free-motion files read
by `factr2 calibrate --from-logs` (keys, units, the edge cases), its checkpoints loaded as estimators, and
ours written in its layout: H5 -> calibrate -> our checkpoint -> official layout -> loaded back, same
estimates to 1e-6."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torch import nn

from calibration.next.checkpoint import load_checkpoint
from calibration.next.estimator import NextEstimator, batch_tau_f
from calibration.next.logs import read_logs
from calibration.next.official import write_official
from factr2_teleop.session.pairs import load_next
from hardware.errors import ConfigError
from tests.next_h5_helpers import RATE_HZ, free_motion, write_next_h5
from tests.test_import_lerobot import _cli
from tests.test_policies_inputs import _one_line_error

pytest.importorskip("h5py")


def test_h5_keys_units_unequal_episodes_and_ns_timestamps(tmp_path):
    p = write_next_h5(tmp_path / "a.h5", lengths=(300, 180))
    runs = read_logs(p, RATE_HZ)
    assert [len(r.log.t) for r in runs] == [300, 180] and [r.name for r in runs] == ["a_ep_0000", "a_ep_0001"]
    q, qd, q_cmd, tau = free_motion(300, seed=0)
    log = runs[0].log
    assert log.units == "N*m" and log.joint_names == [f"joint{i + 1}" for i in range(6)]
    # float32 data; int64 ns stamps near 1.76e18 ns: t keeps its ns (1.76e9 s as float64 would not: ~2e-7 s)
    np.testing.assert_allclose(log.t, np.arange(300) * 0.02, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(log.q, q.astype(np.float32))
    np.testing.assert_array_equal(log.qd, qd.astype(np.float32))
    np.testing.assert_array_equal(log.q_cmd, q_cmd.astype(np.float32))
    np.testing.assert_array_equal(log.tau, tau.astype(np.float32))
    assert runs[0].notes == []


def test_h5_missing_and_short_keys(tmp_path):
    p = write_next_h5(tmp_path / "nov.h5", lengths=(200,), drop=("joint_vel", "joint_cmd"))
    (r,) = read_logs(p, RATE_HZ)
    assert r.log.q_cmd is None
    assert any("no qd" in n for n in r.notes) and any("no q_cmd" in n for n in r.notes)
    p = write_next_h5(tmp_path / "short.h5", lengths=(200,), short=("measured_joint_torque", 150))
    (r,) = read_logs(p, RATE_HZ)
    assert len(r.log.t) == 150 and "kept the 150 rows with the same timestamps" in r.notes[0]
    p = write_next_h5(tmp_path / "notorque.h5", lengths=(200, 100), drop=("measured_joint_torque",))
    with pytest.raises(ConfigError, match="no a torque key") as e:
        read_logs(p, RATE_HZ)
    assert "factr2_next_h5_v1" in str(e.value) and "ep_0000" in str(e.value)


@pytest.mark.parametrize("make, words", [
    (lambda p: p.write_bytes(b"not hdf5 at all"), ["cannot open as HDF5"]),
    (lambda p: write_next_h5(p, schema="something_else"), ["schema is 'something_else'"]),
    (lambda p: write_next_h5(p, lengths=()), ["no ep_NNNN episode groups"]),
    (lambda p: write_next_h5(p, arms=("left", "right")), ["holds arms left, right", "a.h5::left"]),
])
def test_h5_not_the_schema_is_one_line_error(tmp_path, capsys, make, words):
    p = tmp_path / "a.h5"
    make(p)
    rc, _, err = _cli(capsys, "calibrate", "--from-logs", p, "--out", tmp_path / "cal")
    _one_line_error(rc, err, *words)
    rc, _, err = _cli(capsys, "calibrate", "--from-logs", f"{p}::middle", "--out", tmp_path / "cal")
    assert rc == 2 and "Traceback" not in err


def test_h5_calibrate_official_layout_round_trip(tmp_path, capsys):
    """H5 -> calibrate -> our checkpoint -> official layout -> loaded back: the same estimates (1e-6 N*m),
    also with a gate (folded into the official head: 1e-5 relative)."""
    p = write_next_h5(tmp_path / "free.h5", lengths=(1500, 1200, 900), arms=("left", "right"))
    rc, out, err = _cli(capsys, "calibrate", "--from-logs", f"{p}::left", "--out", tmp_path / "cal",
                        "--prior", "none", "--rate-hz", "50", "--max-seconds", "4", "--hidden", "32",
                        "--no-plots")
    assert rc == 0, err
    rc, out, err = _cli(capsys, "export", "next-official", tmp_path / "cal" / "next.json",
                        "--out", tmp_path / "off")
    assert rc == 0 and "official NEXT layout, 6 joints" in out, err
    ours = load_checkpoint(tmp_path / "cal" / "next.json")
    back = load_checkpoint(tmp_path / "off")
    assert back.joint_names == ours.joint_names and back.rate_hz == 50.0
    log = read_logs(f"{p}::left", RATE_HZ)[2].log
    a = batch_tau_f(ours, log.q, log.qd, log.q_cmd, tau=log.tau)
    b = batch_tau_f(back, log.q, log.qd, log.q_cmd, tau=log.tau)
    ok = np.isfinite(a).all(1)
    assert ok.sum() == len(a) - ours.history + 1
    assert np.abs(a[ok] - b[ok]).max() <= 1e-6
    rng = np.random.default_rng(0)
    ours.model.set_gate(rng.uniform(0.3, 1.0, 6).tolist(), rng.normal(0, 0.2, 6).tolist())
    write_official(ours, tmp_path / "off_gate")
    g = batch_tau_f(ours, log.q, log.qd, log.q_cmd, tau=log.tau)
    h = batch_tau_f(load_checkpoint(tmp_path / "off_gate"), log.q, log.qd, log.q_cmd, tau=log.tau)
    # the folded head diag(g) W is rounded to float32 once more than g * (W h): a few float32 ulps of a
    # ~1 N*m output, and the CPU's summation order decides how many (1.3e-6 seen on one machine), so the
    # bound is relative; a wrong fold is off by ~0.1 N*m
    np.testing.assert_allclose(h[ok], g[ok], rtol=1e-5, atol=1e-6)
    # a checkpoint with a physics prior has no official layout: one line
    rc, _, err = _cli(capsys, "calibrate", "--from-logs", f"{p}::left", "--out", tmp_path / "cal2",
                      "--prior", "data-only", "--rate-hz", "50", "--max-seconds", "2", "--hidden", "16",
                      "--no-plots")
    assert rc == 0, err
    rc, _, err = _cli(capsys, "export", "next-official", tmp_path / "cal2" / "next.json", "--out",
                      tmp_path / "off2")
    _one_line_error(rc, err, "no official layout", "physics prior", "--prior none")


class _OfficialLstm(nn.Module):
    """The official regressor's shape, written here from its description (LSTM, then Linear-ReLU-Linear on
    the last step; no dropout: the last layer is head.2)."""

    def __init__(self, n_in, n_out, hidden=128, layers=2, head_hidden=256):
        super().__init__()
        self.lstm = nn.LSTM(n_in, hidden, num_layers=layers, batch_first=True)
        self.head = nn.Sequential(nn.Linear(hidden, head_hidden), nn.ReLU(), nn.Linear(head_hidden, n_out))

    def forward(self, x):
        y, _ = self.lstm(x)
        return self.head(y[:, -1])


def _official_run(d, history=20, n_joints=6):
    torch.manual_seed(0)
    net = _OfficialLstm(3 * n_joints, n_joints, hidden=32, head_hidden=64).eval()
    d.mkdir()
    torch.save({"model_state_dict": net.state_dict(), "input_size": 3 * n_joints, "output_size": n_joints,
                "history": history, "model": {"type": "lstm", "hidden_size": 32, "num_layers": 2,
                                              "head_hidden": 64, "dropout": 0.0}}, d / "model.pt")
    rng = np.random.default_rng(0)
    norm = {"x_mean": rng.normal(0, 0.1, 3 * n_joints).astype(np.float32),
            "x_std": rng.uniform(0.5, 2, 3 * n_joints).astype(np.float32),
            "y_mean": rng.normal(0, 0.5, n_joints).astype(np.float32),
            "y_std": rng.uniform(0.5, 3, n_joints).astype(np.float32)}
    np.savez(d / "normalization.npz", **norm)
    (d / "metrics.json").write_text(json.dumps({"arm": "left", "train_loss": [0.5], "val_loss": [0.6]}))
    (d / "config.yaml").write_text("data:\n  history: 20\nmodel:\n  type: lstm\n  hidden_size: 32\n")
    return net, norm


def test_official_checkpoint_is_an_estimator(tmp_path):
    net, norm = _official_run(tmp_path / "run")
    ck = load_checkpoint(tmp_path / "run")
    assert ck.history == 20 and ck.rate_hz == 50.0 and ck.units == "N*m" and ck.prior is None
    q, qd, q_cmd, tau = free_motion(120)
    x = np.concatenate([q, qd, q_cmd - q], 1).astype(np.float32)
    xn = (x - norm["x_mean"]) / norm["x_std"]
    with torch.no_grad():  # the official inference, window by window
        ref = np.stack([net(torch.from_numpy(xn[None, k - 19 : k + 1])).numpy()[0] for k in range(19, 120)])
    ref = ref * norm["y_std"] + norm["y_mean"]
    got = batch_tau_f(ck, q, qd, q_cmd, tau=tau)
    np.testing.assert_allclose(got[19:], ref, atol=1e-5)
    est = load_next(tmp_path / "run", "follower")  # teleop's streaming estimator (--checkpoint RUN_DIR)
    assert isinstance(est, NextEstimator)
    for k in range(120):
        e = est.update(q[k], qd[k], q_cmd[k], tau[k])
    np.testing.assert_allclose(e.tau_ext, tau[119] - ref[-1], atol=1e-4)


def test_official_checkpoint_that_does_not_fit_is_one_line_error(tmp_path):
    _official_run(tmp_path / "run")
    (tmp_path / "run" / "model.pt").write_bytes(b"garbage")
    with pytest.raises(ConfigError, match="model.pt"):
        load_checkpoint(tmp_path / "run")
    d = tmp_path / "gru"
    _official_run(d)
    sd = torch.load(d / "model.pt", weights_only=True)
    sd["model"]["type"] = "gru"
    torch.save(sd, d / "model.pt")
    with pytest.raises(ConfigError, match="only the official LSTM"):
        load_checkpoint(d)
