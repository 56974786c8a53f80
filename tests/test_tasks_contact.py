"""Task contact settings (SIMULATED): an aligned peg goes in, a misaligned one jams on the fixture, and no
contact interpenetrates beyond the stated depth (docs/tasks.md)."""

import numpy as np
import pytest

from hardware.sim.tasks import peg_insert as PEG
from hardware.sim.tasks.contact_check import lower_held_peg

MAX_PENETRATION_M = 0.0005  # the stated bound: half the clearance


@pytest.mark.parametrize("offset_m", [0.0, 0.0003, 0.0015])  # the 2 mm chamfer guides it in
def test_aligned_peg_goes_in(offset_m):
    r = lower_held_peg(offset_m=offset_m)
    assert r["inserted"] and r["bottom_z_m"] < 0.002
    assert r["max_penetration_m"] < MAX_PENETRATION_M


@pytest.mark.parametrize("kw", [{"offset_m": 0.0035}, {"offset_m": -0.004}, {"yaw_rad": np.deg2rad(5)}])
def test_misaligned_peg_jams(kw):
    r = lower_held_peg(**kw)
    assert not r["inserted"]
    assert r["bottom_z_m"] > PEG.DEPTH_M - PEG.CHAMFER_M - 0.0005  # it stays at the hole's mouth
    assert r["max_penetration_m"] < MAX_PENETRATION_M


def test_press_fit_seats_when_aligned_not_when_off():
    from hardware.sim.tasks.contact_check import press_held_block

    ok = press_held_block(offset_m=0.0)
    assert ok["seated"] and ok["max_penetration_m"] < 0.0003  # the 0.2 mm interference, and no more
    off = press_held_block(offset_m=0.005)
    assert not off["seated"]
