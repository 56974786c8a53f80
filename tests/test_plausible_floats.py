"""Device._plausible (hardware/roles.py): its float path for the usual sample against the numpy form it
replaced (all_within on q - q_ok, the accepted arrays copied every sample), on sequences of samples with
glitches, NaN and a restart (hypothesis): the same samples out, bit for bit, and the same counters. Also
FollowerCommand.targets against the dataclass's own constructor."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.roles import Device
from hardware.safety import PLAUSIBLE_JUMP_RAD, implausible_jump
from hardware.types import STATUS_IMPLAUSIBLE, STATUS_STALE, FollowerCommand, JointLimits, JointState

N = 3


class _Dev(Device):
    def connect(self) -> None: ...
    def _disconnect_bus(self) -> None: ...
    def _read(self): return None
    @property
    def is_connected(self) -> bool: return True
    def _go_safe(self, reason) -> None: ...


def _ref_plausible(state: dict, st: JointState) -> tuple[JointState, int]:
    """The numpy form (before the float path) of Device._plausible for a reading that does not wrap."""
    q = np.asarray(st.q, dtype=float)
    if state.get("q_ok") is None or not math.isfinite(st.t):
        state["q_ok"], state["t_ok"] = q.copy(), np.full(q.shape, st.t)
        return st, 0
    with np.errstate(invalid="ignore"):
        within = bool(np.all(np.abs(q - state["q_ok"]) <= PLAUSIBLE_JUMP_RAD))
    if within:
        np.copyto(state["q_ok"], q)
        state["t_ok"].fill(st.t)
        return st, 0
    bad = implausible_jump(q, state["q_ok"], st.t - state["t_ok"])
    if not bad.any():
        np.copyto(state["q_ok"], q)
        state["t_ok"].fill(st.t)
        return st, 0
    good = ~bad
    state["q_ok"][good], state["t_ok"][good] = q[good], st.t
    status = np.asarray(st.status, dtype=np.uint32).copy()
    status[bad] |= np.uint32(STATUS_IMPLAUSIBLE | STATUS_STALE)
    return dataclasses.replace(st, q=np.where(bad, state["q_ok"], q), status=status), int(bad.sum())


STEP = st.one_of(st.floats(-0.1, 0.1), st.sampled_from([0.5, -3.0, np.nan, np.inf, 0.2, -0.2, 0.0]))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.lists(STEP, min_size=N, max_size=N),
                          st.sampled_from([0.002, 0.0, 0.05, np.nan])), min_size=1, max_size=25))
def test_float_path_is_the_numpy_form(steps):
    lim = JointLimits(q_min=np.full(N, -10.0), q_max=np.full(N, 10.0), v_max=np.ones(N),
                      tau_max=np.ones(N), tau_rate_max=np.ones(N))
    dev, ref, q, t = _Dev("d", lim), {}, np.zeros(N), 0.0
    rejected = 0
    for dq, dt in steps:
        q = np.where(np.isfinite(q), q, 0.0) + np.asarray(dq)
        t = t + dt if math.isfinite(dt) else t
        z = np.zeros(N)
        stamp = t if math.isfinite(dt) else float("nan")
        s = JointState(stamp, q.copy(), z, z, z, z, z, np.zeros(N, np.uint32))
        want, n = _ref_plausible(ref, s)
        got = dev._plausible(s)
        rejected += n
        assert got.q.tobytes() == want.q.tobytes() and got.status.tobytes() == want.status.tobytes()
        assert dev.safety.jumps_rejected == rejected


def test_targets_is_the_dataclass():
    q = np.array([0.1, -0.2])
    assert FollowerCommand.targets(q, 0.03) == FollowerCommand(q=q, gripper=0.03)
    assert FollowerCommand.targets(q) == FollowerCommand(q=q)
    with pytest.raises(dataclasses.FrozenInstanceError):
        FollowerCommand.targets(q).q = q
