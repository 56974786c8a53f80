"""SIMULATED single-sample encoder spikes (lockstep, seeded): rejected and said, never followed."""

from __future__ import annotations

import numpy as np
import pytest

from factr2_teleop.demo.fault_run import run_with_faults
from hardware.safety import implausible_jump
from hardware.sim.faults import SPIKE_RAD, parse_fault
from tests.fault_helpers import run_fault, said

SECONDS = 1.5


def test_implausible_jump_is_pure_and_scales_with_time():
    q0 = np.zeros(3)
    assert implausible_jump(np.array([0.5, 0.1, np.nan]), q0, 0.004).tolist() == [True, False, False]
    assert not implausible_jump(np.array([0.5, 0.0, 0.0]), q0, 1.0).any()  # long gap: it may have moved


@pytest.fixture(scope="module")
def no_fault():
    return run_with_faults([], seconds=SECONDS)


@pytest.mark.parametrize("who", ["leader", "follower"])
def test_spike_is_rejected_not_followed(who, no_fault):
    out = run_fault(f"spike_{who}@0.8", seconds=SECONDS)
    assert out.jumps_rejected >= 1
    assert said(out, f"{who} encoder jump rejected")
    # the same seeded run without the spike: the follower's commands barely differ (a followed leader spike
    # moved them 0.53 rad before the check existed; holding the previous sample moves them ~0.002 rad)
    a, b = out.follower_q_sent, no_fault.follower_q_sent
    n = min(len(a), len(b))
    assert np.abs(a[:n] - b[:n]).max() < 0.01 * SPIKE_RAD
    # what the pair used (and a recording holds) never shows the jump
    assert np.abs(np.diff(out.follower_q_read, axis=0)).max() < 0.1 * SPIKE_RAD


def test_damiao_follower_spike_is_rejected_not_followed():
    """sim-yam: the Damiao follower's encoder glitches once (DamiaoEmulator.spike_rad)."""
    out = run_with_faults([parse_fault("spike_follower@0.8")], seconds=SECONDS, rig="sim-yam")
    assert out.error is None and out.violations == 0 and out.safe_at_end
    assert out.jumps_rejected >= 1 and said(out, "follower encoder jump rejected")
    assert np.abs(np.diff(out.follower_q_read, axis=0)).max() < 0.1 * SPIKE_RAD
