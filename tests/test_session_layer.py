"""The session layer: the CLI, the terminal app and the demo build identical arm pairs (gains, estimator,
feedback mode, recording hook) from identical options, and a teleop recording holds what a policy needs."""

from __future__ import annotations

from argparse import Namespace

import numpy as np
import pytest

from factr2_teleop.teleop.feedback import FeedbackConfig


def signature(ts) -> list[dict]:
    """What a built pair does, from the objects themselves (not from the options that made them)."""
    out = []
    for p in ts.pairs:
        fb, est = p.law.feedback, p.estimator
        out.append({
            "name": p.cfg.name, "mode": p.mode, "dt_s": p.dt_s, "leader": p.leader.name,
            "follower": p.follower.name, "rate_hz": ts.loop.rate_hz,
            "gain": fb.gain.tolist(), "clip": fb.clip.tolist(), "enabled": fb.cfg.enabled,
            "gate_on_contact": fb.cfg.gate_on_contact, "t_high": fb.cfg.t_high_nm, "t_low": fb.cfg.t_low_nm,
            "soft_start": repr(p.cfg.soft_start), "mapping": repr(p.cfg.mapping),
            "stale": (p.cfg.leader_stale_s, p.cfg.follower_stale_s),
            "estimator": type(est).__name__ if est is not None else None,
            "est_k": None if est is None else getattr(est, "k", getattr(est, "k_o", np.zeros(0))).tolist(),
            "est_period": getattr(est, "period_s", None),
            # one recording hook: the loop calls the session's per-tick hook, which feeds SessionRecording
            "hook": ts.loop.recorder.__func__.__qualname__,
        })
    return out


@pytest.mark.parametrize("mode", ["dob", "pp", "ground_truth"])
def test_cli_app_and_demo_build_identical_pairs(mode):
    from factr2_teleop.commands.teleop import options as cli_options
    from factr2_teleop.demo.task import DemoConfig, DemoRun
    from factr2_teleop.session.teleop import TeleopSession
    from factr2_teleop.tui.runtime import RigRuntime
    from factr2_teleop.tui.teleop_ctl import TeleopController
    from hardware.connect import open_rig

    d = FeedbackConfig()
    sigs = {}
    with open_rig("sim-piper", clock="lockstep") as s:
        args = Namespace(mode=mode, checkpoint=None, rate=500.0)
        sigs["cli"] = signature(TeleopSession(s, cli_options(args)))
        rt = RigRuntime("sim-piper")
        rt.session = s  # the app's runtime on the same open rig
        sigs["app"] = signature(TeleopController(rt, rate_hz=500.0, mode=mode, gain=d.gain).build())
    demo = DemoRun(DemoConfig(mode=mode, clock="lockstep", seconds=1.0, gain=[d.gain] * 6, clip_nm=d.clip_nm,
                              t_high_nm=d.t_high_nm, t_low_nm=d.t_low_nm))
    try:
        sigs["demo"] = signature(demo.teleop)
    finally:
        demo.close()
    assert sigs["cli"] == sigs["app"] == sigs["demo"]
    assert sigs["cli"][0]["mode"] == mode and sigs["cli"][0]["hook"] == "TeleopSession._on_tick"


def test_teleop_recording_holds_frames_actions_and_estimates(tmp_path):
    """A lockstep teleop session recorded with the rig's camera: frames at the camera rate on the rig clock,
    the follower's action after the safety layer, tau_ext, all under hardware.features names."""
    from factr2_teleop.session.pairs import TeleopOptions
    from factr2_teleop.session.teleop import TeleopSession
    from hardware.cameras.mujoco_camera import TwinCamera
    from hardware.connect import open_rig
    from hardware.features import rig_features
    from hardware.recording.reader import Recording

    with open_rig("sim-piper", clock="lockstep") as s:
        if not s.cameras or not all(isinstance(c, TwinCamera) for c in s.cameras.values()):
            pytest.skip("sim-piper has no twin camera")
        ts = TeleopSession(s, TeleopOptions(mode="dob"))
        rec = ts.record(tmp_path)
        try:
            rec.start_episode("test")
        except Exception as e:  # noqa: BLE001 -- no OpenGL on this machine
            pytest.skip(f"no offscreen rendering: {e}")
        ts.loop.run(duration_s=1.0)
        ts.close_recording()
        stats = rec.camera_stats["scene"]
        feats = rig_features(s.rig)
    assert stats.failed == 0 and stats.captured >= 0.99 * (stats.expected - 1)
    r = Recording(rec.path)
    ep = r.episodes[0]
    sig = ep.signals()
    for name in ("follower.joint.pos", "follower.joint.tau_ext", "action.joint.pos", "action.gripper.pos",
                 "leader.joint.pos"):
        assert name in feats and name in sig, name
    t_act, q_act = sig["action.joint.pos"]
    assert q_act.shape[1] == 6 and np.all(np.isfinite(q_act)) and len(t_act) >= 400
    frames = ep.frames("scene")
    assert len(frames) >= 28 and frames.rgb(0).shape == feats["observation.images.scene"].shape
    # frames on the rig clock, one per 1/30 s, each the state at a control tick (2 ms)
    assert np.all(np.abs(np.diff(frames.t) - 1 / 30) < 0.0021)
    t_js = ep.topic("/follower/joint_state").t
    assert np.min(np.abs(t_js[:, None] - frames.t[None, :]), axis=0).max() < 1e-6  # a frame per tick time


def test_a_recording_error_reported_after_the_last_health_check_is_said_at_close():
    """A writer starved by other work can report a full disk after the loop's last health check: the
    session says it as the recording closes, once, and a new recording's error is said again."""
    from types import SimpleNamespace

    from factr2_teleop.session.pairs import TeleopOptions
    from factr2_teleop.session.teleop import TeleopSession
    from hardware.connect import open_rig

    class LateError:  # the recording's close() returns the writer's status, its error set late
        camera_stats: dict = {}

        def close(self, why=""):
            return SimpleNamespace(error="the disk is full at /x; the file is complete up to 1.0 s")

    with open_rig("sim-piper", clock="lockstep") as s:
        ts = TeleopSession(s, TeleopOptions(mode="dob"))
        ts.recording = LateError()
        status = ts.close_recording("end")
        ts.recording = LateError()
        ts.close_recording("again")  # said already: once per recording
        texts = [m[2] for m in ts.loop.snapshot().messages if m[1] == "recording"]
    assert status.error.startswith("the disk is full")
    assert texts == [f"{status.error} -- found as the recording closed"]
