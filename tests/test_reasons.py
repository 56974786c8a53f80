"""Typed reasons (hardware.reasons): every user-facing reason message is rendered from one template per kind,
and no behaviour depends on its words. Each scenario here runs twice, once with the real messages and once
with every template replaced by a different string (a translation table), and what it did -- counters,
states, the commands at the wire, the JSON a run stores -- must be identical. SIMULATED, lockstep."""

from __future__ import annotations

import numpy as np
import pytest

from hardware import reasons
from hardware.reasons import Reason, render

pytest.importorskip("mujoco")


def _translated(kind) -> str:
    return f"<<{type(kind).__name__}.{kind.name} übersetzt>>"  # no field of the detail: nothing to parse


def _import_every_kind() -> None:
    """The modules that register templates (so the table covers them all before it is translated)."""
    import calibration.next.collect  # noqa: F401
    import factr2_teleop.session.rollout  # noqa: F401
    import factr2_teleop.teleop.pair  # noqa: F401
    import factr2_teleop.tui.stops  # noqa: F401
    import hardware.can_bus  # noqa: F401
    import hardware.realtime  # noqa: F401
    import hardware.safety  # noqa: F401
    import policies.labels.labelling  # noqa: F401
    import policies.rollout.schedule  # noqa: F401


def twice(monkeypatch, scenario):
    """(scenario's result with the real messages, with every message translated); the translated run must
    have said translated words (else the scenario showed no message and proves nothing)."""
    _import_every_kind()
    plain = scenario()
    with monkeypatch.context() as m:
        for kind in list(reasons.MESSAGES):
            m.setitem(reasons.MESSAGES, kind, _translated(kind))
        translated = scenario()
    return plain, translated


def _said_translated(messages) -> bool:
    return any("übersetzt" in str(x) for x in messages)


def test_every_kind_has_a_template_and_renders_without_its_words(monkeypatch):
    _import_every_kind()
    for kind in reasons.MESSAGES:
        assert isinstance(kind.value, str) and kind.value  # the stable key counters and JSON use
    with monkeypatch.context() as m:
        m.setitem(reasons.MESSAGES, next(iter(reasons.MESSAGES)), "x")
        assert render(Reason(next(iter(reasons.MESSAGES)))) == "x"
    assert render(None) == "" and render("a note") == "a note"


# -- a policy rollout: refused chunks (non-finite, beyond the limits), a stall, waiting ----------------------
class ScriptedRunner:
    """A PolicyRunner stand-in: chunks around the follower's start pose, request `seq`; bad ones on cue."""

    cameras: list = []
    uses_objects = False

    def __init__(self, pair, dt: float = 0.05, horizon: int = 8):
        from policies.rollout.schedule import Chunk

        self.Chunk, self.pair, self.dt, self.h = Chunk, pair, dt, horizon
        self.seq, self.ready = 0, []

    def submit(self, obs, now: float) -> None:
        self.seq += 1
        if 6 <= self.seq <= 9:
            return  # the policy stalls: no chunk
        q0 = np.asarray(self.pair.q_home, float)
        a = np.tile(np.append(q0 + 0.002 * self.seq, 0.0), (self.h, 1))
        if self.seq == 3:
            a[2:, 1] = np.nan
        elif self.seq == 4:
            a[:, 1] += 10.0  # rad: far beyond joint 2's range
        self.ready.append(self.Chunk(t_obs=now, actions=a, dt=self.dt, seq=self.seq))

    def take(self) -> list:
        out, self.ready = self.ready, []
        return out


def _rollout_scenario() -> dict:
    from factr2_teleop.session.pairs import TeleopOptions
    from factr2_teleop.session.rollout import RolloutSession
    from factr2_teleop.session.rollout_pair import PolicyTarget, TargetArm
    from hardware.connect import open_rig
    from hardware.features import rig_features
    from hardware.rigs.rig import load_rig
    from policies.rollout.schedule import RECEDING, ChunkSchedule

    with open_rig(load_rig("sim-piper"), clock="lockstep", seed=0) as s:
        ts = RolloutSession(s, TeleopOptions(mode="none"))
        pair = ts.pairs[0]
        lim = pair.follower.safety.limits
        runner = ScriptedRunner(pair)
        sched = ChunkSchedule(mode=RECEDING, dt=runner.dt, q_min=lim.q_min, q_max=lim.q_max, k_exec=2)
        n = pair.follower.n_joints
        arm = TargetArm(pair, "follower", slice(0, n), n)  # joints, then the gripper column
        target = PolicyTarget([arm], runner, sched, rig_features(s.rig), frames=lambda now: {})
        pair.follow(target.for_pair(0))
        sent, states = [], []

        def hook(r):
            if target.state != "run" and r.t >= 0.1:
                target.run(r.t)
            sent.append(None if pair.sent is None else np.append(pair.sent.q, pair.sent.hold))
            states.append(pair.phase)

        ts.hooks.append(hook)
        ts.loop.run(duration_s=1.2)
        said = [m for _, _, m in ts.loop.snapshot().messages] + list(pair.messages)
        out = {"holds": dict(pair.holds), "accepted": sched.accepted, "nonfinite": sched.nonfinite,
               "outside_limits": sched.outside_limits, "states": states,
               "sent": np.array([x if x is not None else np.full(len(sent[-1]), np.nan) for x in sent]),
               "safety_holds": pair.follower.safety.holds, "said": said}
    return out


def test_a_rollout_does_the_same_whatever_its_messages_say(monkeypatch):
    plain, tr = twice(monkeypatch, _rollout_scenario)
    assert plain["nonfinite"] == 1 and plain["outside_limits"] == 1 and plain["accepted"] >= 5
    assert plain["states"][-1] == "coupled"  # following the policy again after the stall
    assert plain["holds"]["policy output not finite"] == 1 and plain["holds"]["policy stalled"] >= 1
    assert "waiting to start" not in plain["holds"]  # waiting is no fault
    for k in ("holds", "accepted", "nonfinite", "outside_limits", "states", "safety_holds"):
        assert plain[k] == tr[k], k
    np.testing.assert_array_equal(plain["sent"], tr["sent"])  # the follower's commands, bit for bit
    assert not _said_translated(plain["said"]) and _said_translated(tr["said"])


# -- teleop: a silent leader puts the follower on hold, then it re-couples -----------------------------------
def _teleop_scenario() -> dict:
    from factr2_teleop.demo.task import DemoConfig, DemoRun

    run = DemoRun(DemoConfig(seconds=1.2, mode="ground_truth", clock="lockstep", rate_hz=250.0))
    try:
        emu = run.session.twin.devices["leader"].emulator

        def fault(rec):
            t = rec.t - run.operator.t0
            emu.set_silent(0.5 < t < 0.7)

        run.teleop.hooks.append(fault)
        run.run()
        t, q = run.wire_f.arrays()
        return {"t": t, "q": q, "hold": np.array(run.wire_f.hold), "phases": [r[1] for r in run._rows],
                "leader_last_fault_kind": reasons.kind_of(run.pair.follower.safety.last_fault),
                "said": [m[2] for m in run.loop.snapshot().messages]}
    finally:
        run.close()


def test_teleop_holds_and_recouples_the_same_whatever_its_messages_say(monkeypatch):
    plain, tr = twice(monkeypatch, _teleop_scenario)
    assert plain["hold"].any() and "coupled" in plain["phases"][-10:]
    for k in ("t", "q", "hold"):
        np.testing.assert_array_equal(plain[k], tr[k], err_msg=k)
    assert plain["phases"] == tr["phases"] and plain["leader_last_fault_kind"] == tr["leader_last_fault_kind"]
    assert not _said_translated(plain["said"]) and _said_translated(tr["said"])


# -- a refused real-time request: one thread refused (keep trying), not permitted (stop trying) --------------
def _realtime_scenario(monkeypatch) -> dict:
    import errno
    import os
    import threading

    from hardware import realtime as RT

    out = {}
    cases = (("refused", OSError(errno.EBUSY, "busy")), ("not permitted", PermissionError(errno.EPERM, "no")))
    for name, error in cases:
        def refuse(*a, _e=error):
            raise _e

        monkeypatch.setattr(RT.os, "sched_setscheduler", refuse)
        monkeypatch.setattr(RT.os, "sched_getscheduler", lambda tid: os.SCHED_OTHER, raising=False)
        stop = threading.Event()
        other = threading.Thread(target=stop.wait, daemon=True)
        other.start()
        pt = RT.ProcessThreads(priority=5)
        pt.refresh()
        out[name] = (pt.note is None, reasons.kind_of(pt.note), render(pt.note))
        stop.set()
        other.join()
    return out


def test_a_refused_realtime_request_is_judged_by_its_kind(monkeypatch):
    monkeypatch.delenv("FACTR2_NO_RT", raising=False)
    plain, tr = twice(monkeypatch, lambda: _realtime_scenario(monkeypatch))
    assert plain["refused"][0] and not plain["not permitted"][0]  # refused: keep trying; not permitted: stop
    assert {k: v[:2] for k, v in plain.items()} == {k: v[:2] for k, v in tr.items()}
    assert "übersetzt" in tr["not permitted"][2] and "übersetzt" not in plain["not permitted"][2]


# -- contact thresholds: what a run stores, and what resuming it compares and reads back ---------------------
def _thresholds_scenario() -> dict:
    from calibration.next.ident import NextId
    from policies.labels.labelling import Thresholds, ThresholdSource, phases_identity, source_kind

    runs = {"given": Thresholds.given(1.0, 3.0),
            "recording": Thresholds(0.5, 0.9, Reason.of(ThresholdSource.RECORDING, tared=True, episodes=2,
                                                        samples=400), "payload"),
            "next": Thresholds(0.6, 0.9, Reason.of(ThresholdSource.NEXT, next_id=NextId("x/next", "0" * 12),
                                                   val_l1_sum=0.3))}
    return {k: (phases_identity(th.to_dict()), source_kind(th.to_dict()), th.to_dict()["source"])
            for k, th in runs.items()}


def test_threshold_sources_resume_the_same_whatever_their_messages_say(monkeypatch):
    plain, tr = twice(monkeypatch, _thresholds_scenario)
    for k in plain:
        assert plain[k][:2] == tr[k][:2], k  # the resume identity and the kind read back
        assert plain[k][2] != tr[k][2]  # the stored message (for people) did change
    legacy = {"t_low": 1.0, "t_high": 3.0, "source": "recording: Otsu split of ...", "pre_contact_s": 1.0}
    from policies.labels.labelling import ThresholdSource, source_kind

    assert source_kind(legacy) is ThresholdSource.RECORDING  # runs written before the kind was stored


def test_a_run_from_before_the_kind_was_stored_still_resumes():
    from policies.labels.labelling import Thresholds, ThresholdSource
    from policies.labels.phases import LABEL_RULE, PRE_CONTACT_S
    from policies.training.run import _compare

    new = Thresholds(0.5, 0.9, Reason.of(ThresholdSource.RECORDING, tared=True, episodes=2, samples=400),
                     "payload").to_dict()
    old = {"t_low": 0.5, "t_high": 0.9, "pre_contact_s": PRE_CONTACT_S, "tare": "payload", "rule": LABEL_RULE,
           "source": "recording: Otsu split of log ||tau_ext||_1, tared, 2 episodes, 399 samples"}
    assert "phases" not in _compare({"phases": old}, {"phases": new})  # same thresholds, same kind of source
    # a run labelled before the contact runs (no rule stored) does not resume on the new labels
    assert "phases" in _compare({"phases": {k: v for k, v in old.items() if k != "rule"}}, {"phases": new})
    assert "phases" in _compare({"phases": old | {"source": "given"}}, {"phases": new})  # another kind
    assert "phases" in _compare({"phases": old | {"t_high": 1.0}}, {"phases": new})
