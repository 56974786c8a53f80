"""Every twin task names what a camera could detect (Task.detectables): true poses only, in the base frame;
the detector's settings come from the defaults, the task and the rig file (SIMULATED)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from hardware.arms import load_arm
from hardware.errors import ConfigError
from hardware.sim.perception import PerceptionParams, PoseDetector
from hardware.sim.tasks import TASKS, get_task, scene_model
from hardware.sim.tasks.base import task_perception


@pytest.mark.parametrize("name", sorted(TASKS))
def test_detectables_are_true_poses_only(name):
    task = get_task(name)
    m = scene_model(load_arm("piper"), "table", task)
    d = mujoco.MjData(m)
    params = task.reset(m, d, np.random.default_rng(11))
    mujoco.mj_forward(m, d)
    det = task.detectables(m, d, params)
    assert det and all(isinstance(k, str) for k in det)
    for pos, rot in det.values():
        assert np.shape(pos) == (3,) and np.shape(rot) == (3, 3)
        assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-6)
    # the detector runs on them
    pd = PoseDetector(task_perception(task), tuple(det))
    pd.reset(np.random.default_rng(0))
    seen = pd.update(1.0, det, np.zeros(3))
    assert set(seen) == set(det)


@pytest.mark.parametrize("name,pos_key,yaw_key,obj", [("peg-insert", "hole_pos", "hole_yaw", "hole"),
                                                     ("press-fit", "base_pos", "base_yaw", "base"),
                                                     ("wipe", "area_pos", "area_yaw", "area")])
def test_existing_tasks_report_their_targets(name, pos_key, yaw_key, obj):
    task = get_task(name)
    m = scene_model(load_arm("piper"), "table", task)
    d = mujoco.MjData(m)
    params = task.reset(m, d, np.random.default_rng(5))
    mujoco.mj_forward(m, d)
    pos, rot = task.detectables(m, d, params)[obj]
    assert np.allclose(pos, params[pos_key]) and math.atan2(rot[1, 0], rot[0, 0]) == pytest.approx(
        params[yaw_key])


def test_task_then_rig_settings_override_the_defaults(monkeypatch):
    task = get_task("peg-insert")
    assert task_perception(task) == PerceptionParams()
    monkeypatch.setattr(type(task), "perception", {"bias_pos_m": 0.004, "rate_hz": 15.0})
    p = task_perception(task, {"rate_hz": 10.0})
    assert (p.bias_pos_m, p.rate_hz) == (0.004, 10.0)
    with pytest.raises(ConfigError, match="twin.perception"):
        task_perception(task, {"rate": 10.0}, where="sim-piper.toml: twin.perception")


def test_rig_file_perception_table(tmp_path):
    from hardware.rigs.rig import RIG_DIR, load_rig

    text = (RIG_DIR / "sim-piper.toml").read_text()
    good = tmp_path / "mine.toml"
    good.write_text(text + "\n[twin.perception]\nbias_pos_m = 0.004\nlatency_s = 0.2\n")
    rig = load_rig(good)
    p = task_perception(get_task("peg-insert"), rig.twin.perception)
    assert (p.bias_pos_m, p.latency_s) == (0.004, 0.2)
    bad = tmp_path / "bad.toml"
    bad.write_text(text + "\n[twin.perception]\nbias_pos = 0.004\n")
    with pytest.raises(ConfigError) as e:
        load_rig(bad)
    assert "twin.perception" in str(e.value) and str(bad) in str(e.value) and "\n" not in str(e.value)
