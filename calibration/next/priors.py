"""Every physics prior kind under NEXT, by name: what `--prior` accepts and what a checkpoint's "prior" dict
is read back as. The kinds (each a calibration.next.prior_base.TorquePrior):

- "none": the paper's plain NEXT (no prior);
- "description", "identified": the arm description's rigid-body model, as is or corrected on the data
  (calibration.next.prior; torque in N*m);
- "identified-current": the identified prior with a current-per-torque scale per joint, for logs in A
  (calibration.next.scaled_prior; an imported URDF is enough);
- "data-only": the grey box without a description (calibration.next.data_prior; any units).

This module is the only one that knows all of them; the implementations import prior_base, not each other.
"""

from __future__ import annotations

from calibration.next import data_prior, prior, scaled_prior
from calibration.next.prior_base import TorquePrior

PRIOR_KINDS = ("none", "description", "identified", scaled_prior.KIND, data_prior.KIND)
_READERS = {"description": prior.Prior.from_dict, "identified": prior.Prior.from_dict,
            scaled_prior.KIND: scaled_prior.ScaledPrior.from_dict,
            data_prior.KIND: data_prior.DataPrior.from_dict}


def prior_from_dict(d: dict, n_joints: int | None = None) -> TorquePrior:
    """A checkpoint's prior of any kind; ValueError when unreadable."""
    reader = _READERS.get(d.get("kind"))
    if reader is None:
        raise ValueError(f"prior kind {d.get('kind')!r}")
    return reader(d, n_joints)


def make_stream(p: TorquePrior, rate_hz: float | None = None):
    """The one-sample-at-a-time form of a prior of any kind."""
    return p.stream(rate_hz)


def fit(kind: str, arm: str | None, units: str, runs: list[tuple]) -> TorquePrior | None:
    """The prior of `kind` fitted on free-motion runs (t, q, qd, tau[, temperature]) in `units` ("N*m" or
    "A"). "auto": identified with a description (identified-current for logs in A), else data-only.
    ValueError names what is missing for a kind that cannot be fitted."""
    if kind == "auto":
        kind = data_prior.KIND if arm is None else ("identified" if units == "N*m" else scaled_prior.KIND)
    if kind not in PRIOR_KINDS:
        raise ValueError(f"unknown prior {kind!r}: use one of {PRIOR_KINDS} or auto")
    if kind == "none":
        return None
    if kind == data_prior.KIND:
        return data_prior.fit_data_prior([r[:4] for r in runs])
    if arm is None:
        raise ValueError(f"the {kind} prior needs the arm description (--arm, or factr2 arm import)")
    if kind == scaled_prior.KIND:
        return scaled_prior.fit_scaled_prior(arm, runs)
    if units != "N*m":
        raise ValueError(f"the {kind} prior needs torque in N*m (logs in {units}): use --prior "
                         f"{scaled_prior.KIND} (fits a current-per-torque scale) or data-only")
    return prior.fit_prior(kind, arm, runs)
