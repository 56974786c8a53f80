"""PiperFollower._build_state (the usual sample: one unpack per kind of frame, its low-speed and status part
kept while those frames' bytes stay the same) against _build_state_general (frame by frame), bit for bit, on
any frames, receive times (stale, NaN), hold flags and sequences of them."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as hst

from hardware.clock import LockstepClock
from hardware.piper import protocol as P
from hardware.piper.config import PiperFollowerConfig
from hardware.piper.follower import PiperFollower, default_limits

_IDS = (*P.ID_JOINT_FB, *P.ID_HIGH_SPEED, *P.ID_LOW_SPEED, P.ID_STATUS, P.ID_GRIPPER_FB)
_frame = hst.one_of(hst.binary(min_size=8, max_size=8),
                    hst.sampled_from([bytes(8), b"\x00\x01\x02\x03\x04\x05\x06\x07", b"\xff" * 8]))
_time = hst.one_of(hst.floats(0.9, 1.0), hst.sampled_from([1.0, 0.0, math.nan]))
_tick = hst.tuples(hst.dictionaries(hst.sampled_from(_IDS), hst.tuples(_frame, _time)), hst.booleans())


def _same(a, b) -> None:
    if a is None or b is None:
        assert a is None and b is None
        return
    for name, x in vars(a).items():
        y = getattr(b, name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name
        else:
            assert np.float64(x).tobytes() == np.float64(y).tobytes(), name


@settings(max_examples=500, deadline=None)
@given(hst.lists(_tick, min_size=1, max_size=6), hst.booleans())
def test_fast_sample_is_the_general_one(ticks, full):
    fast = PiperFollower(PiperFollowerConfig(channel="unused"), default_limits(), clock=LockstepClock())
    general = PiperFollower(PiperFollowerConfig(channel="unused"), default_limits(), clock=LockstepClock())
    for frames, hold in ticks:
        if full:  # every id there at first: the usual path taken, then some frames replaced
            frames = {i: frames.get(i, (bytes(8), 1.0)) for i in _IDS}
        for f in (fast, general):
            f.in_safe_state = hold
            for i, (d, t) in frames.items():
                f.decoder.latest[i], f.decoder.t_rx[i] = d, t
        _same(fast._build_state(1.0), general._build_state_general(1.0))
        assert fast.status_info == general.status_info
