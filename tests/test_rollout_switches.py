"""The rollout's tri-state switches, resolved by one pure function (session/rollout_plan.py)."""

from pathlib import Path

import pytest

from factr2_teleop.session.rollout_plan import RolloutHooks, RolloutOptions, resolve_switches


def _sw(simulated=True, hooks=None, **kw):
    opts = RolloutOptions(rig="sim-piper", policy=Path("RUN"), **kw)
    return resolve_switches(opts, hooks or RolloutHooks(), simulated)


def test_a_lockstep_twin_without_watchers_is_lean_and_inline():
    sw = _sw()
    assert (sw.realtime, sw.takeover, sw.lean, sw.threaded) == (False, False, True, False)


def test_a_real_rig_runs_in_real_time_with_takeover_never_lean():
    sw = _sw(simulated=False, lean=True)
    assert (sw.realtime, sw.takeover, sw.lean, sw.threaded) == (True, True, False, True)


@pytest.mark.parametrize("kw, hooks", [({"record": Path("out")}, None),
                                       ({}, RolloutHooks(on_start=lambda ts, target, eps: None))])
def test_a_recording_or_a_watcher_turns_lean_off_unless_asked(kw, hooks):
    assert not _sw(hooks=hooks, **kw).lean
    assert _sw(hooks=hooks, lean=True, **kw).lean


def test_a_scripted_operator_turns_takeover_on_and_takeover_turns_lean_off():
    sw = _sw(hooks=RolloutHooks(operator=lambda ts, target, eps, tk: None))
    assert sw.takeover and not sw.lean
    assert not _sw(hooks=RolloutHooks(operator=lambda *a: None), takeover=False).takeover
    assert not _sw(takeover=True, lean=True).lean


def test_asked_switches_win():
    sw = _sw(realtime=True, threaded=False, takeover=False)
    assert sw.realtime and not sw.threaded and not sw.takeover and not sw.lean
