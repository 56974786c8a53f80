"""Phase labels of recorded episodes (the I/O around policies.labels.phases).

tau_ext comes from the recording (/<arm>/tau_ext, what NEXT estimated live), or, with a NEXT checkpoint
(`--next CKPT`), from that checkpoint run offline over the logged follower joint states (episodes recorded
without an estimate, or with an older model): policies.labels.episode_tau. Bimanual rigs: the score sums
every follower's joints, on the first follower's timeline, and so do the thresholds (one noise floor per arm).

Tare on grasp (policies.labels.tare, on by default): while a follower's gripper holds an object, the object's
load, estimated on the free motion right after the grasp, is taken out of that arm's tau_ext before the score,
for the labels and for the recording thresholds alike. The policy's force input (EpisodeLabels.tau_ext) stays
the raw estimate, and so does live force feedback (teleop never labels).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import numpy as np

from calibration.next.ident import json_path
from hardware.errors import UserError
from hardware.importers import lerobot as LR
from hardware.reasons import Reason, messages
from hardware.recording.reader import Episode
from policies.data.recordings import ArmSet, episode_id, recorded_next_checkpoints
from policies.labels import motion_recording as MR
from policies.labels import motion_residual as M
from policies.labels import phases as P
from policies.labels import tare as T
from policies.labels.episode_tau import NextModel, episode_tau_ext, load_next
from policies.labels.tare_recording import episode_tare


class ThresholdSource(Enum):
    """Where contact thresholds came from (hardware.reasons); the value is what a run's meta["phases"] stores
    as source_kind."""

    GIVEN = "given"  # the operator's LOW:HIGH
    RECORDING = "recording"  # the episodes' own scores (detail: tared, episodes, samples)
    NEXT = "next"  # the NEXT checkpoint's free-motion noise (detail: next_id, val_l1_sum [N*m])
    DATASET = "dataset"  # a factr2 LeRobot export's own labels, imported (thresholds: those that made them)


def _recording_source(tared: bool, episodes: int, samples: int, motion: bool = False) -> str:
    eps = f"{episodes} episode{'s' if episodes != 1 else ''}"
    score = "the motion residual of tau_ext" if motion else "||tau_ext||_1"
    return f"recording: Otsu split of log {score}{', tared' if tared else ''}, {eps}, {samples} samples"


messages({
    ThresholdSource.GIVEN: "given",
    ThresholdSource.RECORDING: _recording_source,
    ThresholdSource.NEXT: "NEXT {next_id.short} (val_l1 sum {val_l1_sum:.4g})",
    ThresholdSource.DATASET: "dataset: " + LR.PHASES_LINE,
})


@dataclass
class Thresholds:
    t_low: float
    t_high: float
    source: Reason  # a ThresholdSource reason
    tare: str = "off"  # held-load tare of the scores they apply to: policies.labels.tare.TARE_METHODS
    motion: M.MotionResidual | None = None  # --contact-score motion: the score's fitted motion part

    @classmethod
    def given(cls, t_low: float, t_high: float, tare: str = "off") -> Thresholds:
        """Thresholds [N*m] set by hand."""
        return cls(float(t_low), float(t_high), Reason.of(ThresholdSource.GIVEN), tare)

    def to_dict(self) -> dict:
        """A training run's meta["phases"]: "source" the message (for people), "source_kind" its kind;
        "tare" only when the scores were tared (a run from before the tare, or with --no-tare, reads the same
        and so resumes)."""
        d = {"t_low": self.t_low, "t_high": self.t_high, "source": str(self.source),
             "source_kind": self.source.key, "pre_contact_s": P.PRE_CONTACT_S, "rule": P.LABEL_RULE}
        if self.motion is not None:  # the default score writes nothing new: runs from before it resume
            d |= {"score": "motion", "motion": self.motion.to_dict(), "rule": P.LABEL_RULE + MOTION_RULE}
        return d | ({"tare": self.tare} if self.tare != "off" else {})


def source_kind(phases: dict) -> ThresholdSource | None:
    """The kind of source a run's meta["phases"] names. Runs written before source_kind was stored: read from
    the start of their message, which was fixed then ("given", "recording: ...", "NEXT ..."); the one place
    a message is read back, for those files only."""
    if phases.get("source_kind"):
        return ThresholdSource(phases["source_kind"])
    text = str(phases.get("source", ""))
    legacy = {"given": ThresholdSource.GIVEN, "recording": ThresholdSource.RECORDING,
              "NEXT": ThresholdSource.NEXT}
    return legacy.get(text.split(":")[0].split(" ")[0])


def phases_identity(phases: dict) -> dict:
    """What of a run's meta["phases"] must match to resume it: the thresholds, pre-contact time, tare and
    the kind of source (not the source's message, which is for people)."""
    kind = source_kind(phases)
    return {k: v for k, v in phases.items() if k not in ("source", "source_kind")} | {
        "source_kind": kind.value if kind is not None else None}


THRESHOLD_SOURCES = ("recording", "next")  # --thresholds words; or LOW:HIGH [N*m]
TARE_DEFAULT = "payload"  # measured against the twin's truth (docs/first_labels.md, bench/label_truth.py)
MOTION_RULE = f"; score: motion residual (keep {M.KEEP_FRACTION:g}, {M.PASSES} passes)"


@dataclass(frozen=True)
class LabelChoice:
    """What a label command asked for: the thresholds (as resolve_thresholds takes them) and the tare
    method (policies.labels.tare.TARE_METHODS; `--no-tare` is "off")."""

    thresholds: object
    tare: str = TARE_DEFAULT
    score: str = "l1"  # policies.labels.motion_residual.CONTACT_SCORES


def resolve_thresholds(
    given, next_model: NextModel | None, episodes: list[Episode], arms: ArmSet, tare: str | None = None
) -> Thresholds:
    """given: (LOW, HIGH) [N*m]; "recording": from the episodes' own scores (Otsu,
    policies.labels.phases.recording_thresholds; tau_ext recorded, or from --next offline), the CLI's default;
    "next" or None: from the free-motion noise of the --next checkpoint, else of the checkpoint the recording
    names (None keeps the library's former default for its callers); or a LabelChoice carrying one
    of these and the tare. tare: policies.labels.tare.TARE_METHODS (default TARE_DEFAULT); the recording
    source splits the tared scores, and the labels of these thresholds are tared alike."""
    score = "l1"
    if isinstance(given, LabelChoice):
        given, tare, score = given.thresholds, given.tare if tare is None else tare, given.score
    tare = TARE_DEFAULT if tare is None else tare
    if tare not in T.TARE_METHODS:
        raise UserError(f"unknown tare method {tare!r}", fix=f"one of {', '.join(T.TARE_METHODS)}")
    if score not in M.CONTACT_SCORES:
        raise UserError(f"unknown contact score {score!r}", fix=f"one of {', '.join(M.CONTACT_SCORES)}")
    if score == "motion" and given != "recording":
        raise UserError("--contact-score motion has no thresholds in N*m: it is split by the recording's own "
                        "scores", where="--thresholds", fix="use --thresholds recording (the default)")
    carried = [dataset_phases(ep) for ep in episodes]
    if given == "recording" and next_model is None and carried and all(c is not None for c in carried):
        made = carried[0][1]  # a factr2 export's labels: trained on as they are (label_episode)
        th = Thresholds(made["t_low"], made["t_high"], Reason.of(ThresholdSource.DATASET))
    elif given == "recording":
        th = _recording_thresholds(episodes, arms, next_model, tare, score)
    elif given is None or given == "next":
        th = _checkpoint_thresholds(next_model, episodes, arms)
    else:
        th = Thresholds.given(given[0], given[1])
    th.tare = tare
    return th


def dataset_phases(ep: Episode) -> tuple[list, dict, float] | None:
    """(label changes [[row, label], ...], the thresholds that made them, fps [Hz]) of an episode imported
    from a factr2 LeRobot export (hardware.importers.lerobot.IMPORT_PHASES), else None."""
    text = ep.recording.info.get(LR.IMPORT_PHASES)
    if not text:
        return None
    d = json.loads(text)
    return d["episodes"][ep.index], d["thresholds"], float(d["fps"])


def _recording_thresholds(episodes, arms, next_model, tare: str, score_kind: str = "l1") -> Thresholds:
    motion = _fit_motion(episodes, arms, next_model, tare) if score_kind == "motion" else None
    scores = [episode_scores(ep, arms, tare, next_model, motion)[0] for ep in episodes]
    score = np.concatenate(scores) if scores else np.zeros(0)
    try:
        lo, hi = P.recording_thresholds(score)
    except ValueError:
        raise UserError(
            "too few tau_ext samples to derive contact thresholds from the recordings",
            where=str(episodes[0].recording.path) if episodes else "",
            fix="pass --thresholds LOW:HIGH [N*m] (or --thresholds next: from the NEXT checkpoint)",
        ) from None
    n = int(np.sum(np.isfinite(score)))
    src = Reason.of(ThresholdSource.RECORDING, tared=tare != "off", episodes=len(episodes), samples=n,
                    **({"motion": True} if motion is not None else {}))
    return Thresholds(lo, hi, src, motion=motion)


def _fit_motion(episodes, arms, next_model, tare: str) -> M.MotionResidual:
    """--contact-score motion: the fit over the set's (tared) tau_ext and joint velocities."""
    taus, qds = [], []
    for ep in episodes:
        t, tau, _ = episode_tau_ext(ep, arms, next_model)
        taus.append(_tared(ep, arms, t, tau, tare))
        qds.append(MR.episode_q_dot(ep, arms, t))
    try:
        return M.fit_motion_residual(np.concatenate(taus), np.concatenate(qds))
    except ValueError as e:
        raise UserError(f"--contact-score motion: {e}", where=str(episodes[0].recording.path),
                        fix="record more episodes, or use the default score") from None


def _checkpoint_thresholds(next_model, episodes, arms) -> Thresholds:
    model = next_model
    if model is None:
        named = next((ids for ids in map(recorded_next_checkpoints, episodes) if ids), ())
        if named and json_path(named[0].path).exists():
            model = load_next(named[0].path)
    if model is None:
        raise UserError(
            "no NEXT checkpoint to derive the contact thresholds from (the recordings name none)",
            where=str(episodes[0].recording.path),
            fix="pass --next CKPT (the NEXT checkpoint), or --thresholds recording or LOW:HIGH [N*m]",
        )
    val_l1 = (model.ck.metrics or {}).get("val_l1")
    if not val_l1:
        raise UserError(
            "the NEXT checkpoint has no free-motion noise (metrics.val_l1)",
            where=str(model.path),
            fix="retrain it with `factr2 calibrate`, or pass --thresholds recording or LOW:HIGH",
        )
    lo, hi = P.default_thresholds(val_l1)
    n = len(arms.followers)
    src = Reason.of(ThresholdSource.NEXT, next_id=model.id, val_l1_sum=float(np.sum(val_l1)))
    return Thresholds(n * lo, n * hi, src)


def _tared(ep, arms, t, tau, tare: str) -> np.ndarray:
    return tau if tare == "off" else T.tared(tau, episode_tare(ep, arms, t, tau, tare)[0])


def episode_scores(ep: Episode, arms: ArmSet, tare: str, next_model: NextModel | None = None,
                   motion: M.MotionResidual | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(score (N,) of the tared tau_ext, raw score (N,), held (N,) bool, tare note) [N*m] on the times of
    episode_tau_ext (tare "off": the raw score twice). With `motion` the score is its residual score of the
    tared tau_ext (dimensionless, policies.labels.motion_residual); the raw one stays ||tau_ext||_1."""
    t, tau, _ = episode_tau_ext(ep, arms, next_model)
    raw = P.contact_score(tau)
    if tare == "off":
        load, held, note = None, np.zeros(len(t), bool), ""
        tared = tau
    else:
        load, held, note = episode_tare(ep, arms, t, tau, tare)
        tared = T.tared(tau, load)
    if motion is not None:
        f = M.residual_score(motion, tared, MR.episode_q_dot(ep, arms, t))
        return M.smooth_score(t, f), raw, held, note
    return (raw if load is None else P.contact_score(tared)), raw, held, note


@dataclass
class EpisodeLabels:
    episode: str
    t: np.ndarray  # [s] the tau_ext samples' times
    tau_ext: np.ndarray  # (N, J) [N*m], as estimated (not tared: the policy's force input)
    score: np.ndarray  # (N,) ||tau_ext - held load||_1 [N*m]: what the labels split (raw without tare)
    phases: np.ndarray  # (N,) int8: policies.labels.phases.FREE / PRE_CONTACT / CONTACT
    source: str
    raw_score: np.ndarray | None = None  # (N,) ||tau_ext||_1 before the tare (None: same as score)
    held: np.ndarray | None = None  # (N,) bool: a gripper holds an object (tared there)
    tare: str = "off"

    def shares(self) -> np.ndarray:
        return P.phase_shares(self.phases)

    def at(self, t_grid: np.ndarray) -> np.ndarray:
        """Phase at each grid time: the label of the latest sample at or before it (FREE before the first)."""
        i = np.searchsorted(self.t, np.asarray(t_grid, float), side="right") - 1
        return np.where(i >= 0, self.phases[np.clip(i, 0, None)], P.FREE).astype(np.int8)


def label_episode(
    ep: Episode, arms: ArmSet, th: Thresholds, next_model: NextModel | None = None
) -> EpisodeLabels:
    """Phases of one episode with th's thresholds on the score th.tare asks for (raw or tared)."""
    t, tau, source = episode_tau_ext(ep, arms, next_model)
    score, raw, held, note = episode_scores(ep, arms, th.tare, next_model, th.motion)
    if th.tare != "off":
        source += f"; tare {th.tare}" + (f" ({note})" if note else "")
    if th.source.key == ThresholdSource.DATASET.value:  # the dataset's rows, at the force samples' times
        changes, _, fps = dataset_phases(ep)
        phases = LR.labels_at(changes, (t - ep.t_start) * fps)
        source += "; labels: the dataset's phase column"
    else:
        phases = P.label_phases(t, P.contact_runs(score, th.t_low, th.t_high))
    return EpisodeLabels(episode_id(ep), t, tau, score, phases, source, raw, held, th.tare)


PHASE_COLOURS = ("#ffffff", "#f5c26b", "#e4572e")


def plot_labels(lab: EpisodeLabels, th: Thresholds, path: Path) -> Path:
    """The labelling figure: tau_ext per joint and the score with the thresholds, phases shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = lab.t - lab.t[0] if len(lab.t) else lab.t
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    for j in range(lab.tau_ext.shape[1]):
        a1.plot(t, lab.tau_ext[:, j], lw=0.8, label=f"j{j + 1}")
    tared = lab.tare != "off" and lab.raw_score is not None
    if tared:
        a2.plot(t, lab.raw_score, color="0.6", lw=0.6, alpha=0.6, label="||tau_ext||_1 raw")
    a2.plot(t, lab.score, color="k", lw=0.8,
            label=f"||tau_ext - held load||_1 (tare {lab.tare})" if tared else "||tau_ext||_1")
    if tared and lab.held is not None and lab.held.any():
        a2.fill_between(t, 0, 1, where=lab.held, transform=a2.get_xaxis_transform(), color="#4c72b0",
                        alpha=0.08, lw=0, label="gripper holds an object")
    a2.axhline(th.t_high, color="#e4572e", ls="--", lw=0.8, label=f"T_high {th.t_high:.3g}")
    a2.axhline(th.t_low, color="#4c72b0", ls="--", lw=0.8, label=f"T_low {th.t_low:.3g}")
    edges = np.flatnonzero(np.diff(lab.phases.astype(int))) + 1
    starts, stops = np.r_[0, edges], np.r_[edges, len(t)]
    for a in (a1, a2):
        for lo, hi in zip(starts, stops):
            ph = int(lab.phases[lo]) if len(lab.phases) else 0
            if ph != P.FREE and hi > lo:
                a.axvspan(t[lo], t[min(hi, len(t) - 1)], color=PHASE_COLOURS[ph], alpha=0.45, lw=0)
    a1.set_ylabel("tau_ext [N*m]")
    a1.legend(ncol=8, fontsize=7, loc="upper right")
    a2.set_ylabel("score [N*m]")
    a2.set_xlabel("time in episode [s]")
    a2.legend(fontsize=7, loc="upper right")
    sh = lab.shares()
    a1.set_title(
        f"{lab.episode}: free {sh[0]:.0%}, pre-contact (orange) {sh[1]:.0%}, contact (red) {sh[2]:.0%}"
        f"\n[{lab.source}]",
        fontsize=8,
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
