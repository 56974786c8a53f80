"""A real-time loop freezes what start-up made out of Python's collections (factr2_teleop/teleop/loop.py): a
full collection mid-session then walks only what the session made (129 -> 5 ms measured on the dev VM: a stall
of the loop whichever thread triggers it), and the objects are given back to the collector at the end."""

from __future__ import annotations

import gc
import time


def test_realtime_loop_freezes_startup_objects_and_unfreezes_after():
    from factr2_teleop.session.pairs import TeleopOptions
    from factr2_teleop.session.teleop import TeleopSession
    from hardware.connect import open_rig

    seen = []
    with open_rig("sim-piper", clock="realtime") as s:
        ts = TeleopSession(s, TeleopOptions(mode="dob"))
        ts.hooks.append(lambda r: seen.append(gc.get_freeze_count()) if len(seen) < 5 else None)
        ts.loop.start(duration_s=1.0)
        while ts.loop.alive:
            time.sleep(0.05)
        ts.loop.stop(timeout_s=2.0)
    assert seen and min(seen) > 10_000  # start-up's objects (numpy, MuJoCo, the rig) frozen while it ran
    assert gc.get_freeze_count() == 0  # and collectable again once it stopped
