"""A policy is fed the tau_ext estimator it was trained on: NEXT by its checkpoint, another estimator (the
disturbance observer cap-screw's demonstrations are felt through) by the recordings' feedback mode."""
from pathlib import Path
from types import SimpleNamespace

import pytest

from factr2_teleop.session.rollout import estimator_mode
from hardware.errors import UserError
from policies.training.run import _recorded_estimator


def _ep(mode: str | None):
    info = {} if mode is None else {"feedback_mode": mode}
    return SimpleNamespace(recording=SimpleNamespace(info=info))


def test_recorded_estimator_names_the_recordings_modes():
    assert _recorded_estimator([_ep("dob"), _ep("dob")]) == "dob"
    assert _recorded_estimator([_ep("next"), _ep("dob")]) == "dob,next"
    assert _recorded_estimator([_ep(None)]) == ""


def test_rollout_runs_the_estimator_the_policy_was_trained_on():
    ck = Path("next.json")
    assert estimator_mode(ck, None, "", True) == "next"
    assert estimator_mode(None, None, "dob", True) == "dob"  # the recordings' observer, not the rig's default
    assert estimator_mode(None, "dob", "dob", True) == "dob"
    assert estimator_mode(None, None, "dob", False) is None  # no force input: the rig's choice
    assert estimator_mode(None, "pp", "dob,next", True) == "pp"  # mixed recordings name no single one
    assert estimator_mode(None, None, "", True) is None  # policies trained before the key: as before
    with pytest.raises(UserError, match="dob estimator"):
        estimator_mode(None, "next", "dob", True)


def test_cap_screw_demonstrator_feels_through_the_observer():
    from factr2_teleop.tasks.run import CollectConfig, _mode_and_checkpoint
    from hardware.sim.tasks import get_task

    cap = get_task("cap-screw")
    assert cap.operator_feedback == "dob"
    assert _mode_and_checkpoint(CollectConfig(task="cap-screw"), "sim-piper", cap) == ("dob", None)
    assert _mode_and_checkpoint(CollectConfig(task="cap-screw", mode="pp"), "sim-piper", cap) == ("pp", None)
    assert all(get_task(n).operator_feedback is None for n in ("peg-insert", "press-fit", "wipe"))
