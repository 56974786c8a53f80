"""The crash campaign's rollout activity (SIMULATED, real time): `factr2 rollout` of a policy that sees the
joints and force only, beside a YAM twin in a process of its own, frozen 2 s (SIGSTOP, SIGCONT) and stopped
with Ctrl-C: the motors fell back during the freeze (leader Bus Watchdog latched, Damiao damping), 0 N*m from
the leader after it, and the app came back without a jump: the follower, which sank on damping, returns from
where it is at the soft start's speed (bench/crash_trials.py, factr2_teleop/session/rollout_pair.py)."""

from __future__ import annotations

import pytest

from bench.crash_trials import run_crash_trial
from factr2_teleop.teleop.soft_start import SoftStartConfig


@pytest.mark.slow
def test_rollout_frozen_beside_a_process_twin_falls_back_and_comes_back_slowly(tmp_path):
    out = run_crash_trial("rollout", "app_freeze", "sim-yam", 5, tmp_path / "s", 2.0,
                            policies=tmp_path / "policies")
    assert out["played"] and out["error"] is None and not out["traceback"], out.get("error")
    assert out["safe_end"] and out["latched_during_freeze"] and out["leader_tau_after_nm"] == 0.0
    assert out["recovered"] and out["exit"] in (0, 130)
    assert out["follower_speed_after_resume_rad_s"] <= float(SoftStartConfig().rate_limit_rad_s)
    assert any("comes back at the soft start" in m for m in out["messages"]), out["messages"]
