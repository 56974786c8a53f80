"""`factr2 calibrate --from-logs` end to end on small synthetic piper logs and on the UR5 logs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from calibration.next.train import TrainConfig
from calibration.report import calibrate_from_logs
from factr2_teleop.cli import main
from hardware.recording.plain_log import save_plain_log

torch.set_num_threads(1)
UR5 = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ur5_kufieta2014"
TINY = dict(history=10, hidden=16, head_hidden=32, batch_size=256, samples_per_epoch=1024, max_epochs=3,
            threads=1, device="cpu")


def _piper_log(path, seconds=40.0, seed=0, contact=False):
    from calibration.baselines import rigid_body_torque
    from hardware.arms import load_arm

    arm = load_arm("piper")
    model = arm.pinocchio_model()
    t = np.arange(int(seconds * 125)) / 125.0
    rng = np.random.default_rng(seed)
    f, ph = rng.uniform(0.1, 0.4, 6), rng.uniform(0, 6, 6)
    mid, amp = (arm.limits.q_min + arm.limits.q_max) / 2, 0.3 * (arm.limits.q_max - arm.limits.q_min)
    q = mid + amp * np.sin(2 * np.pi * f * t[:, None] + ph)
    qd = amp * 2 * np.pi * f * np.cos(2 * np.pi * f * t[:, None] + ph)
    qdd = -amp * (2 * np.pi * f) ** 2 * np.sin(2 * np.pi * f * t[:, None] + ph)
    tau = rigid_body_torque(model, q, qd, qdd) + 0.3 * np.tanh(qd / 0.05) + 0.1 * qd
    arrays = dict(t=t, q=q, qd=qd, q_cmd=q + 0.02 * qd, joint_names=np.array(arm.joint_names))
    if contact:
        c = (t > 0.4 * seconds) & (t < 0.7 * seconds)
        ext = np.zeros_like(q)
        ext[c, 1] = 1.5
        arrays.update(tau_ext_true=ext, contact=c)
        tau = tau + ext
    return save_plain_log(path, tau_m=tau, **arrays)


def test_calibrate_from_logs_with_arm(tmp_path):
    train = [_piper_log(tmp_path / "free1.npz", 20, seed=1), _piper_log(tmp_path / "free2.npz", 20, seed=2)]
    ev = [_piper_log(tmp_path / "held.npz", 10, seed=3), _piper_log(tmp_path / "touch.npz", 10, seed=4,
                                                                     contact=True)]
    out = tmp_path / "cal"
    rep = calibrate_from_logs(train, out, ev, arm="piper", cfg=TrainConfig(**TINY))
    on_disk = json.loads((out / "report.json").read_text())
    assert on_disk["units"] == rep["units"] == "N*m"
    for key in ("train_seconds", "data_minutes", "device", "methods", "files"):
        assert key in on_disk
    for m in ("next", "observer", "filic", "raw"):
        v = on_disk["methods"][m]
        assert len(v["free_l1"]) == 6 and len(v["contact_l1"]) == 6
        assert v["free_l1_mean"] == pytest.approx(np.mean(v["free_l1"]))
    assert on_disk["files"]["held"]["next"]["contact_l1"] is None  # no truth in that file
    touch = on_disk["files"]["touch"]
    # the model-based baselines know the rigid body exactly: on joint 2 in contact they see the 1.5 N*m
    # (plus unmodelled friction); raw torque does not
    assert touch["filic"]["contact_l1"][1] < touch["raw"]["contact_l1"][1]
    est = np.load(out / "estimates" / "touch.npz")
    assert {"t", "tau_ext_next", "tau_ext_observer", "tau_ext_filic", "tau_ext_raw"} <= set(est.files)
    assert (out / "next.safetensors").exists() and (out / "next.json").exists()
    assert (out / "plots" / "touch.png").exists() and "| next |" in (out / "report.md").read_text()


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["calibrate", "--from-logs", str(tmp_path / "nope.npz"), "--out", str(tmp_path / "o")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["calibrate", "--rig", "no-such-rig", "--out", str(tmp_path / "o")]) == 2
    (tmp_path / "bad.npz").write_bytes(b"garbage")
    assert main(["calibrate", "--from-logs", str(tmp_path / "bad.npz"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 2  # rig error + bad file error


@pytest.mark.skipif(not UR5.is_dir(), reason="UR5 logs not present at <repo>/../shared/data/ur5_kufieta2014")
def test_ur5_logs_in_current_units(tmp_path):
    rep = calibrate_from_logs([UR5 / "Movement_No6_Acc_slow_Verify_Model.npz"], tmp_path / "ur5",
                              [UR5 / "Movement_No7_Acc_slow_Verify_Model_short.npz"],
                              cfg=TrainConfig(**TINY), plots=False)
    assert rep["units"] == "A"
    m = rep["files"]["Movement_No7_Acc_slow_Verify_Model_short"]
    assert m["observer"]["free_l1"] is None and m["filic"]["free_l1"] is None
    assert m["ridge"]["free_l1_mean"] < m["raw"]["free_l1_mean"]  # the fit explains part of the current
    assert np.isfinite(m["next"]["free_l1_mean"])


def test_heldout_blocks_spread_over_the_run():
    """The calibration pipeline's one held-out policy (CLI, terminal app and demo alike)."""
    from calibration.pipeline import CalibrationConfig, split_mask

    cfg = CalibrationConfig(heldout_frac=0.15, rate_hz=100.0)  # 20 s blocks

    def heldout_blocks(n, frac, block):
        assert frac == cfg.heldout_frac and block == 2000
        return split_mask(n, cfg)

    m = heldout_blocks(70_000, 0.15, 2000)  # 35 blocks of 20 s at 100 Hz, every 7th held out
    assert 0.12 < m.mean() < 0.18 and not m[:2000].any()
    starts = np.flatnonzero(np.diff(m.astype(int)) == 1) + 1
    assert len(starts) == 5 and starts[-1] > 0.8 * len(m)  # held-out blocks reach the end of the run
    short = heldout_blocks(6000, 0.15, 2000)  # 1 min: shorter blocks, still ~1/7 held out
    assert 0.1 < short.mean() < 0.2 and not short[:800].any()
