"""What every physics prior under NEXT is (calibration/next/prior.py, data_prior.py, scaled_prior.py), and the
filtering they share; calibration.next.priors reads any of them back from a checkpoint.

A prior predicts the free-space part of the logged torque signal from (q, q_dot, q_ddot). NEXT trains on
what it leaves, and the estimate is tau_ext = F(tau_m - prior) - f_theta (calibration.next.prior's docstring
explains the midpoint acceleration and the filters F). The interface:

    p.kind, p.arm, p.uses_temperature
    p.to_dict()                                    what a checkpoint stores (priors.prior_from_dict reads it)
    p.stream(rate_hz).update(q, qd, tau[, temperature, dt]) -> this sample's tau_f part
    p.torque(t, q, qd, tau[, temperature]) -> (N, n): tau - F(tau - prediction) over one run

Units: the log's (N*m, or A for the data-only and the current-scaled priors).
"""

from __future__ import annotations

import numpy as np

ACCEL_CUTOFF_HZ = 20.0  # the fit's low-pass on the residual [Hz]
FILTER_ORDER = 2  # first-order sections in cascade, fit and estimate (2: half the noise of 1, a bit more lag)
# The estimate's adaptive low-pass, chosen by bench/tune_next_filter.py on pushed twin runs that are not the
# calibration's evaluation (contact error within 1 % of the best with free-motion error no worse than the
# fixed 20 Hz low-pass; of those the lowest free-motion error):
EST_MIN_HZ = 8.0  # cut-off while the residual is steady [Hz]
EST_BETA = 4.0  # cut-off rise per unit rate of change of the residual [Hz per N*m/s]
EST_DERIV_HZ = 5.0  # low-pass on that rate of change [Hz]
FRICTION_VEL = 0.02  # tanh width of the smooth Coulomb term [rad/s] (above typical velocity noise)
SHARP_VEL = 0.005  # tanh width of the sharp Coulomb and the Stribeck terms [rad/s]


class TorquePrior:
    """Base of the priors: subclasses set kind, arm, uses_temperature and implement to_dict and stream."""

    kind: str = ""
    arm: str = ""
    uses_temperature: bool = False

    def to_dict(self) -> dict:
        raise NotImplementedError

    def stream(self, rate_hz: float | None = None):
        """The one-sample-at-a-time form (update(q, qd, tau, temperature=None, dt=None) -> tau_f part)."""
        raise NotImplementedError

    def torque(self, t, q, qd, tau, temperature=None) -> np.ndarray:
        """The prior's part of tau_f for every sample of one run (N, n), filters started at its first sample:
        tau - F(tau - prediction). This default steps the stream (subclasses may batch the same sum)."""
        s = self.stream()
        dts = np.diff(np.asarray(t, float), prepend=t[0])  # the first sample starts the filters
        temp = [None] * len(t) if temperature is None else temperature
        return np.array([s.update(q[k], qd[k], tau[k], temp[k], dts[k]) for k in range(len(t))])


def midpoints(t, q, qd, tau):
    """Every sample taken half a sample back, at its backward difference's time (the first sample as is,
    zero acceleration) -> (q, qd, qdd, tau) at the midpoints."""
    t, q, qd, tau = (np.asarray(a, float) for a in (t, q, qd, tau))
    qm, qdm, taum = q.copy(), qd.copy(), tau.copy()
    qdd = np.zeros_like(qd)
    if len(t) > 1:
        dt = np.diff(t)[:, None]
        for mid, a in ((qm, q), (qdm, qd), (taum, tau)):
            mid[1:] = 0.5 * (a[1:] + a[:-1])
        qdd[1:] = np.diff(qd, axis=0) / np.where(dt > 0, dt, np.inf)
    return qm, qdm, qdd, taum


class Lowpass:
    """`order` first-order sections, state started at the first input (no start transient). Cut-off
    [Hz] = cutoff_hz + beta |dx/dt| per element, dx/dt low-passed at deriv_hz (beta 0: fixed)."""

    def __init__(self, cutoff_hz: float, order: int, beta: float = 0.0, deriv_hz: float = EST_DERIV_HZ):
        self.fc, self.order, self.beta, self.tc_d = cutoff_hz, order, beta, 1.0 / (2 * np.pi * deriv_hz)
        self.state = self.prev = self.rate = None

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        x = np.asarray(x, float)
        if self.state is None:
            self.state = [x.copy() for _ in range(self.order)]
            self.prev, self.rate = x.copy(), np.zeros_like(x)
            return x.copy()
        if not dt > 0.0:  # a repeated time stamp: nothing elapsed
            return self.state[-1].copy()
        fc = self.fc
        if self.beta > 0.0:
            self.rate += dt / (dt + self.tc_d) * ((x - self.prev) / dt - self.rate)
            self.prev = x.copy()
            fc = self.fc + self.beta * np.abs(self.rate)
        a = dt / (dt + 1.0 / (2 * np.pi * fc))
        for s in self.state:
            s += a * (x - s)
            x = s
        return x.copy()
