"""The lean rollout (docs/rollout.md "Rollout CPU", SIMULATED, lockstep): what only a recording or a watcher
reads is skipped -- the passive leader's simulation and service, the estimator when the policy observes no
force -- and the rollout is the same: a tiny state policy (the PRIVILEGED object vector, as bench_first
trains) gives the same episodes and the same follower commands at the wire, command for command, with the
cut on and off."""

import numpy as np
import pytest

from factr2_teleop.session.rollout import RolloutHooks, RolloutOptions, run_rollout
from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd

pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def state_runs(wipe_state_runs):
    """{method: RUN} for a policy without force input (base) and one with it (base-torque), trained a few
    steps on one scripted wipe demonstration (collected once per session: conftest.py wipe_state_runs)."""
    for method in ("base", "base-torque"):
        wipe_state_runs[method]  # trained here, in the fixture's setup
    return wipe_state_runs


def _rollout(run, lean: bool) -> tuple[dict, list, dict]:
    """(result, follower commands at the wire (t_sent, q, gripper, hold), what the twin's leader did)."""
    sent, seen = [], {"leader_tau": []}

    def attach(ts, target, eps):
        pair = ts.pairs[0]
        pair.follower.add_command_observer(
            lambda t_issued, t_sent, safe: sent.append((t_sent, np.array(safe.q), safe.gripper, safe.hold)))
        pair.leader.add_command_observer(
            lambda t_issued, t_sent, safe: seen["leader_tau"].append(float(np.abs(safe.tau).max())))
        seen["worlds"] = {n: d.world for n, d in ts.session.twin.devices.items()}
        seen["steps_before"] = {n: w.steps for n, w in seen["worlds"].items()}

    out = run_rollout(RolloutOptions(rig="sim-piper", policy=run, task="wipe", episodes=2, seed=7,
                                     max_seconds=0.6, mode="dob", progress=False, lean=lean),
                      RolloutHooks(on_start=attach)).to_dict()
    seen["steps"] = {n: w.steps - seen["steps_before"][n] for n, w in seen.pop("worlds").items()}
    return out, sent, seen


@pytest.mark.parametrize("method", ["base", "base-torque"])
def test_lean_rollout_sends_the_same_follower_commands(state_runs, method):
    full, sent_full, leader_full = _rollout(state_runs[method], lean=False)
    lean, sent_lean, leader_lean = _rollout(state_runs[method], lean=True)
    assert lean["lean"] and not full["lean"]
    # the same episodes: outcome, progress, stages, duration
    assert lean["episodes"] == full["episodes"] and len(full["episodes"]) == 2
    assert (lean["success_rate"], lean["mean_progress"]) == (full["success_rate"], full["mean_progress"])
    # the same commands at the wire (after the safety layer), bit for bit, and the same policy schedule
    assert len(sent_lean) == len(sent_full) > 500
    for a, b in zip(sent_full, sent_lean):
        assert a[0] == b[0] and np.array_equal(a[1], b[1]) and a[2:] == b[2:]
    keys = ("chunks", "commands_sent", "command_violations", "holds", "targets_clamped", "safety_clipped",
            "refused_outside_limits", "end_follower_held", "end_leader_tau_max_nm")
    assert {k: lean["timing"][k] for k in keys} == {k: full["timing"][k] for k in keys}
    assert lean["timing"]["end_follower_held"] and lean["timing"]["end_leader_tau_max_nm"] == 0.0
    # what was cut: the leader's world stood still, and only its safe state (zero torque: at the start, at
    # the end and when the rig closes) reached its wire, through its safety layer
    assert leader_lean["steps"]["leader"] == 0 < leader_full["steps"]["leader"]
    assert leader_lean["steps"]["follower"] == leader_full["steps"]["follower"]
    assert len(leader_lean["leader_tau"]) <= 3 < len(leader_full["leader_tau"])
    assert max(leader_lean["leader_tau"]) == 0.0
    # the estimator runs only for the policy that reads it
    assert full["feedback_mode"] == "dob"
    assert lean["feedback_mode"] == ("none" if method == "base" else "dob")


def test_lean_is_the_default_only_when_nothing_records_or_watches(state_runs, tmp_path):
    run = state_runs["base"]
    quick = dict(rig="sim-piper", policy=run, task="wipe", episodes=1, seed=7, max_seconds=0.1, mode="dob",
                 progress=False)
    assert run_rollout(RolloutOptions(**quick)).lean
    assert not run_rollout(RolloutOptions(**quick, record=tmp_path)).lean
    assert not run_rollout(RolloutOptions(**quick), RolloutHooks(on_start=lambda *a: None)).lean


def test_the_rested_leader_ends_at_zero_torque_without_a_latched_watchdog(state_runs, caplog):
    """The lean rollout says nothing to its passive leader between the start and the end: its servos' Bus
    Watchdog must not take that for a dead host (a latch, reported at the end as 'no force feedback'). Stood
    down while the leader rests, armed again for the end: no trip, no such line, and the servos end at 0 A,
    torque off."""
    seen = {}

    def attach(ts, target, eps):
        pair = ts.pairs[0]
        seen["leader"], seen["emu"] = pair.leader, ts.session.twin.devices[pair.leader.name].emulator

    out = run_rollout(RolloutOptions(rig="sim-piper", policy=state_runs["base"], task="wipe", episodes=1,
                                     seed=7, max_seconds=0.6, mode="dob", progress=False, lean=True),
                      RolloutHooks(on_start=attach)).to_dict()
    emu, leader = seen["emu"], seen["leader"]
    assert out["lean"] and out["timing"]["end_leader_tau_max_nm"] == 0.0
    assert emu.watchdog_trips == []
    said = [m for m in [*leader.warnings, *caplog.messages, *map(str, out["messages"])] if "had latched" in m]
    assert said == []
    joints = [s for s in emu.servos if s.id in leader.config.ids]
    for s in joints:  # the end: 0 A asked, torque off, the watchdog armed again for it
        assert s.get(p.ADDR_GOAL_CURRENT, signed=True) == 0 and not s.torque_on
        assert s.table[wd.ADDR[0]] == wd.units_for(wd.LEADER_PERIOD_S)
