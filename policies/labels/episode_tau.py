"""Where an episode's tau_ext comes from, for the labels (policies.labels.labelling): the recording's live
estimate (/<arm>/tau_ext, what NEXT estimated while it recorded), or a NEXT checkpoint run offline over the
logged follower joint states (`--next CKPT`: episodes recorded without an estimate, or with an older model).
Bimanual rigs: every follower's joints, on the first follower's timeline. An offline pass is the expensive
part: a NextModel keeps the passes made with it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.next.ident import NextId
from hardware.errors import UserError
from hardware.recording import schemas as S
from hardware.recording.reader import Episode, interp_linear
from policies.data.recordings import ArmSet, episode_id

OFFLINE_RUNS_MAX = 64  # offline NEXT passes a NextModel keeps (episodes); all dropped when full


@dataclass
class NextModel:
    """A loaded NEXT checkpoint and its id (calibration.next.ident), for labelling and the run's record.
    offline_runs: the offline NEXT passes made with it (episode_tau_ext), kept while the model is held, so
    the recording thresholds and the labels pay for one pass per episode; dropped with the model."""

    ck: object  # calibration.next.checkpoint.NextCheckpoint
    path: Path
    id: NextId
    offline_runs: dict = field(default_factory=dict, repr=False, compare=False)


def load_next(path) -> NextModel:
    from calibration.next.checkpoint import load_checkpoint

    ck = load_checkpoint(path)
    return NextModel(ck, Path(path), NextId.of(path))



def _offline_tau_ext(ep: Episode, arm: str, model: NextModel) -> tuple[np.ndarray, np.ndarray]:
    """tau_ext of one arm from the checkpoint run over its logged joint states, at the checkpoint's rate;
    NaN where the window is not full yet (each gap restarts it)."""
    from calibration.next.data import resample_log
    from calibration.next.estimator import batch_tau_f

    ck = model.ck
    if list(ck.joint_names) != list(ep.recording.joint_names(arm) or ck.joint_names):
        raise UserError(
            f"NEXT checkpoint joints {ck.joint_names} differ from the recording's {arm} joints",
            where=str(model.path),
            fix="pass the NEXT checkpoint calibrated on this arm",
        )
    log = ep.to_plain(arm)
    if ck.units == "A":
        log.tau = np.asarray(log.extra["current"], float)
    ts, taus = [], []
    for seg in resample_log(log, ck.rate_hz):
        tau_f = batch_tau_f(ck, seg.q, seg.qd, seg.q_cmd, tau=seg.tau, temperature=seg.temperature)
        ts.append(seg.t)
        taus.append(seg.tau - tau_f)
    if not ts:
        raise UserError(
            f"episode {episode_id(ep)}: too few {arm} joint states for NEXT", where=str(model.path)
        )
    return np.concatenate(ts), np.concatenate(taus)


def _recorded_tau_ext(ep: Episode, arm: str) -> tuple[np.ndarray, np.ndarray] | None:
    topic = S.tau_ext_topic(arm)
    if topic not in ep.recording.topics:
        return None
    ta = ep.topic(topic)
    tau = np.asarray(ta.fields["tau_ext"], float)
    if len(ta) < 2 or not np.isfinite(tau).any():
        return None
    return ta.t, tau


def episode_tau_ext(
    ep: Episode, arms: ArmSet, next_model: NextModel | None = None
) -> tuple[np.ndarray, np.ndarray, str]:
    """(t [s], tau_ext (N, sum of joints) [N*m], source) of an episode: every follower, on the first one's
    timeline. Source "recorded" or "NEXT <id> offline". An offline NEXT pass is kept in the model's
    offline_runs (read-only arrays): the recording thresholds and the labels both need it, and it is the
    expensive part."""
    if next_model is None:
        return _episode_tau_ext(ep, arms, None)
    st = Path(ep.recording.path).stat()  # a recording rewritten in place (trim, delete) is read again
    key = (str(ep.recording.path), st.st_mtime_ns, st.st_size, ep.index, tuple(arms.followers))
    runs = next_model.offline_runs
    if key not in runs:
        if len(runs) >= OFFLINE_RUNS_MAX:
            runs.clear()
        t, tau, source = _episode_tau_ext(ep, arms, next_model)
        t.flags.writeable = tau.flags.writeable = False
        runs[key] = (t, tau, source)
    return runs[key]


def _episode_tau_ext(ep: Episode, arms: ArmSet, next_model: NextModel | None):
    parts = []
    for arm in arms.followers:
        got = _offline_tau_ext(ep, arm, next_model) if next_model is not None else _recorded_tau_ext(ep, arm)
        if got is None:
            raise UserError(
                f"episode {episode_id(ep)} has no estimated tau_ext for {arm}",
                where=str(ep.recording.path),
                fix="pass --next CKPT to estimate it offline from the logged joint states",
            )
        parts.append(got)
    t = parts[0][0]
    tau = np.concatenate([parts[0][1]] + [interp_linear(ti, yi, t) for ti, yi in parts[1:]], axis=1)
    return t, tau, ("recorded" if next_model is None else f"NEXT {next_model.id.short} offline")
