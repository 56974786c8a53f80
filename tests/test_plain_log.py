"""Plain .npz logs: valid files load, bad ones give one ConfigError naming the file and the fix."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.errors import ConfigError
from hardware.recording.plain_log import load_plain_log, save_plain_log


def _arrays(n=50, j=3):
    t = np.linspace(0, 1, n)
    q = np.sin(t)[:, None] * np.ones(j)
    return dict(t=t, q=q, qd=np.cos(t)[:, None] * np.ones(j), q_cmd=q + 0.01, current=q * 2)


def test_current_with_constant_becomes_torque(tmp_path):
    a = _arrays()
    p = save_plain_log(tmp_path / "a.npz", **a, torque_constant=np.array([2.0, 3.0, 4.0]))
    log = load_plain_log(p)
    assert log.units == "N*m" and np.allclose(log.tau, a["current"] * [2, 3, 4])


def test_current_without_constant_stays_in_amps_and_duplicates_dropped(tmp_path):
    a = _arrays()
    a["t"][10] = a["t"][9]
    log = load_plain_log(save_plain_log(tmp_path / "b.npz", **a))
    assert log.units == "A" and len(log.t) == 49 and np.all(np.diff(log.t) > 0)


@pytest.mark.parametrize("mutate, msg", [
    (lambda a: a.pop("q_cmd"), "missing"),
    (lambda a: a.pop("current"), "tau_m or current"),
    (lambda a: a.__setitem__("qd", np.zeros((3, 3))), "qd has shape"),
])
def test_bad_logs_one_line(tmp_path, mutate, msg):
    a = _arrays()
    mutate(a)
    np.savez(tmp_path / "bad.npz", **a)
    with pytest.raises(ConfigError) as e:
        load_plain_log(tmp_path / "bad.npz")
    assert msg in str(e.value) and "bad.npz" in str(e.value) and "\n" not in str(e.value)


def test_garbage_file(tmp_path):
    p = tmp_path / "junk.npz"
    p.write_bytes(b"\x00garbage" * 10)
    with pytest.raises(ConfigError, match="not a readable"):
        load_plain_log(p)


def test_real_ur5_log_loads(ur5_dir):
    log = load_plain_log(ur5_dir / "TEST.npz")
    assert log.units == "A" and log.n_joints == 6 and log.joint_names[1] == "shoulder"


def test_logs_name_their_arm(tmp_path):
    a = _arrays()
    log = load_plain_log(save_plain_log(tmp_path / "a.npz", **a, arm=np.array("piper"),
                                        arm_sha256=np.array("ab" * 32)))
    assert log.arm == "piper" and log.arm_sha256 == "ab" * 32 and "arm" not in log.extra
    assert load_plain_log(save_plain_log(tmp_path / "b.npz", **a)).arm == ""  # older logs: unknown
    np.savez(tmp_path / "bad.npz", **a, arm=np.array([1.0, 2.0]))
    with pytest.raises(ConfigError, match="arm is"):
        load_plain_log(tmp_path / "bad.npz")
