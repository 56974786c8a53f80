"""The fault schedule (hardware/sim/faults.py): parsing KIND@T[:DURATION], one-line errors, seeded draws."""

from __future__ import annotations

import pytest

from hardware.errors import ConfigError
from hardware.sim.faults import KINDS, FaultSpec, parse_fault, random_schedule


def test_parse_with_and_without_duration():
    assert parse_fault("can_busoff@2.5:0.3") == FaultSpec("can_busoff", 2.5, 0.3)
    assert parse_fault("spike_leader@1") == FaultSpec("spike_leader", 1.0, KINDS["spike_leader"][1])


@pytest.mark.parametrize("bad", ["busoff@1", "can_busoff", "can_busoff@x", "can_busoff@1:-2", "can_loss@nan"])
def test_bad_fault_is_one_line_config_error(bad):
    with pytest.raises(ConfigError) as e:
        parse_fault(bad)
    assert "\n" not in str(e.value) and "KIND@T" in str(e.value)


def test_random_schedule_is_seeded_sorted_and_apart():
    kinds = ["can_loss", "dxl_unplug", "spike_follower"]
    a = random_schedule(3, kinds, 6, 1.0, 30.0)
    assert a == random_schedule(3, kinds, 6, 1.0, 30.0) and a != random_schedule(4, kinds, 6, 1.0, 30.0)
    assert sorted(s.kind for s in a) == sorted(kinds * 2)
    for p, q in zip(a, a[1:], strict=False):
        assert q.t_s >= p.t_s + p.duration_s + 1.0 - 1e-9
    assert a[-1].t_s + a[-1].duration_s <= 30.0
