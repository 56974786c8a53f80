"""Find the episodes a training run, a labelling or an export uses: recordings (files or folders) -> episodes,
with the arm set checked once for all of them.

A corrupt or unreadable recording is skipped with a warning when others remain; none left is a UserError.
Episodes labelled "discard" are left out (the operator threw them away); so are episodes without follower
joint-state samples. Training also leaves out failed and incomplete episodes by default (`training_episodes`):
the paper trains on successful demonstrations, and an episode cut off by a killed recorder ends mid-motion.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.next.ident import NextId, parse_ids
from hardware.errors import UserError
from hardware.features import POLICY_STATE, Feature, action_of, follower_arms, recorded_features
from hardware.recording import schemas as S
from hardware.recording.reader import UNMARKED, Episode, Recording, interp_linear
from hardware.recording.recover import drop_superseded


@dataclass(frozen=True)
class ArmSet:
    """What every episode of a run must share: follower arms (topic names, "follower" or "left_follower"),
    their joint names, and each arm's model from the rig file ("" when the recording does not say)."""

    followers: tuple[str, ...]
    joint_names: tuple[tuple[str, ...], ...]
    arm_models: tuple[str, ...]

    def describe(self) -> str:
        return ", ".join(
            f"{f} ({m or '?'}: {len(j)} joints)"
            for f, j, m in zip(self.followers, self.joint_names, self.arm_models)
        )

    def to_dict(self) -> dict:
        return {
            "followers": list(self.followers),
            "joint_names": [list(j) for j in self.joint_names],
            "arm_models": list(self.arm_models),
        }


def recording_files(paths, lerobot_map: str | None = None) -> list[Path]:
    """Every .mcap under the given files/folders (folders: their .mcap files, not recursive), sorted; in a
    folder, a damaged file whose `factr2 recover` copy is beside it is left out (the copy holds its data).
    A LeRobotDataset folder is read as its converted recording (hardware/importers/lerobot.py; lerobot_map:
    its --lerobot-map)."""
    from hardware.importers.lerobot import is_lerobot_dataset, lerobot_recordings

    out: list[Path] = []
    for p in map(Path, paths):
        if is_lerobot_dataset(p):
            out += lerobot_recordings(p, lerobot_map)
        elif p.is_dir():
            out += drop_superseded(sorted(
                f for f in p.iterdir() if f.is_file() and f.suffix == ".mcap" and ".tmp-" not in f.name
            ))
        elif p.is_file():
            out.append(p)
        else:
            raise UserError("no such file or folder", where=str(p), fix="check the path")
    return out


def _rig_arm_models(rec: Recording, followers: list[str]) -> list[str]:
    """Each follower's arm model from the recording's rig TOML ("" when absent or unreadable)."""
    text = rec.info.get("rig_toml", "")
    models = {}
    if text:
        try:
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            import tomli as tomllib
        try:
            for d in tomllib.loads(text).get("followers", []):
                name = str(d.get("name", "follower"))
                models[name] = str(d.get("arm", ""))
        except (ValueError, AttributeError, TypeError):
            pass
    return [models.get(f, models.get("follower", "") if len(followers) == 1 else "") for f in followers]


def recording_features(rec: Recording) -> dict[str, Feature]:
    """The features a recording holds, by flat name (hardware.features: the schema its rig declared)."""
    return recorded_features(rec.info, rec.topics)


def arm_set(rec: Recording) -> ArmSet:
    topics = set(rec.topics)
    followers = [a for a in follower_arms(recording_features(rec)) if S.joint_state_topic(a) in topics]
    joints = []
    for f in followers:
        names = rec.joint_names(f)
        if not names:
            ta = rec.topic(S.joint_state_topic(f))
            n = ta.fields["q"].shape[1] if len(ta) else 0
            names = [f"joint{i + 1}" for i in range(n)]
        joints.append(tuple(names))
    return ArmSet(tuple(followers), tuple(joints), tuple(_rig_arm_models(rec, followers)))


def load_episodes(paths, *, keep_discarded: bool = False, lerobot_map: str | None = None
                  ) -> tuple[list[Episode], ArmSet]:
    """All usable episodes of the recordings under `paths` (LeRobotDataset folders too), and their common
    arm set."""
    files = recording_files(paths, lerobot_map)
    if not files:
        raise UserError(
            "no recordings (.mcap) found",
            where=", ".join(map(str, paths)),
            fix="pass recording files or folders written by `factr2 collect --out DIR` (twin tasks) or "
            "`factr2 teleop --record DIR`",
        )
    episodes: list[Episode] = []
    arms: ArmSet | None = None
    first = None
    skipped = []
    for f in files:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # truncation is reported below, once
                rec = Recording(f)
            this = arm_set(rec)
        except (UserError, OSError, ValueError, KeyError) as e:
            skipped.append(f"{f}: {str(e).splitlines()[0][:160]}")
            continue
        if rec.truncated:
            warnings.warn(
                f"{f}: truncated recording (recorder killed?); using what was flushed", stacklevel=2
            )
        if not this.followers:
            skipped.append(f"{f}: no follower joint states")
            continue
        if arms is None:
            arms, first = this, f
        elif this != arms:
            raise UserError(
                f"episodes of different arms or joint sets: {first} has {arms.describe()}, "
                f"this has {this.describe()}",
                where=str(f),
                fix="train on recordings of one rig (one folder per rig)",
            )
        for ep in rec.episodes:
            if ep.outcome == "discard" and not keep_discarded:
                continue
            if len(ep.topic(S.joint_state_topic(arms.followers[0]))) < 2:
                continue
            episodes.append(ep)
    for s in skipped:
        warnings.warn(f"skipped {s}", stacklevel=2)
    if not episodes:
        why = f" ({len(skipped)} unreadable: {skipped[0]})" if skipped else ""
        raise UserError(
            f"no usable episodes{why}",
            where=", ".join(map(str, paths)),
            fix="record episodes with `factr2 collect --out DIR` or `factr2 teleop --record DIR` (discarded "
            "ones are left out)",
        )
    return episodes, arms


def incomplete(ep: Episode) -> bool:
    """The episode was cut off: no stop (recorder killed), or a file without episodes that is truncated."""
    return ep.outcome == "incomplete" or (ep.outcome == UNMARKED and bool(ep.recording.truncated))


def training_episodes(episodes, *, include_failed: bool = False, keep_incomplete: bool = False):
    """The episodes a training run uses, and the skipped ones as {"episode": id, "why": ...}.

    Failed demonstrations (a task's detector or the operator said "failure") and incomplete episodes are
    skipped unless asked for. Episodes without a verdict (a teleop recording without a task) are kept: there
    is nothing to say they failed."""
    kept, skipped = [], []
    for ep in episodes:
        if ep.outcome == "failure" and not include_failed:
            skipped.append({"episode": episode_id(ep), "why": "failed"})
        elif incomplete(ep) and not keep_incomplete:
            skipped.append({"episode": episode_id(ep), "why": "incomplete"})
        else:
            kept.append(ep)
    return kept, skipped


def _count(n: int, what: str) -> str:
    return f"{n} {what} episode" + ("s" if n != 1 else "")


def skipped_line(skipped: list[dict]) -> str:
    """One line for the user: how many episodes were skipped, why, and the flag that keeps them ("" none)."""
    failed = sum(s["why"] == "failed" for s in skipped)
    cut = sum(s["why"] == "incomplete" for s in skipped)
    parts = []
    if failed:
        parts.append(f"{_count(failed, 'failed')} (--include-failed keeps them)")
    if cut:
        parts.append(f"{_count(cut, 'incomplete')} (recording cut off; --keep-incomplete keeps them)")
    return "skipped " + ", ".join(parts) if parts else ""


def episode_id(ep: Episode) -> str:
    return f"{ep.recording.path.name}#{ep.index}"


def parse_episode_ids(text: str) -> tuple[str, ...]:
    """"a.mcap#0-11,b.mcap#3" -> ("a.mcap#0", ..., "a.mcap#11", "b.mcap#3"): episode ids as episode_id names
    them, a range I-J inclusive; ValueError (what is wrong) for anything else."""
    out: list[str] = []
    for item in (s.strip() for s in text.split(",")):
        name, sep, span = item.rpartition("#")
        lo, dash, hi = span.partition("-")
        if not sep or not name or not lo.isdigit() or (dash and not hi.isdigit()):
            raise ValueError(f"{item!r} is not FILE.mcap#N or FILE.mcap#N-M")
        if dash and int(hi) < int(lo):
            raise ValueError(f"{item!r}: the range ends before it starts")
        out += [f"{name}#{i}" for i in range(int(lo), int(hi if dash else lo) + 1)]
    return tuple(dict.fromkeys(out))


def recorded_next_checkpoints(ep: Episode) -> tuple[NextId, ...]:
    """The NEXT checkpoints the recording's metadata names (calibration.next.ident; () when none)."""
    return parse_ids(ep.recording.info.get("next_checkpoint"))


def describe_rig(ep: Episode) -> dict:
    """Rig file and simulated flag of an episode's recording (for checkpoints and exports)."""
    s = ep.recording.info
    return {
        "rig_file": s.get("rig_file", ""),
        "simulated": s.get("simulated", "unknown"),
        "joint_names": json.loads(s.get("joint_names", "{}") or "{}"),
    }


def feature_on_grid(ep: Episode, feature: Feature, grid) -> np.ndarray:
    """A recorded feature on the time grid [s], (T, size), by linear interpolation; NaN outside its samples.
    A scalar (a gripper) that does not report reads 0 (its NaN samples are zeroed first)."""
    ta = ep.topic(feature.topic)
    vals = ta.fields[feature.field]
    if not feature.shape:
        return interp_linear(ta.t, np.nan_to_num(vals), grid)[:, None]
    return interp_linear(ta.t, vals, grid)


def follower_state_action(ep: Episode, arm: str, grid, purpose: str,
                          features: dict[str, Feature] | None = None) -> tuple:
    """One follower's state (q + gripper) and action (commanded q + gripper after the safety layer) on the
    time grid [s], read by feature name: ((T, J + 1), (T, J + 1)); NaN where a signal is missing. UserError
    when the episode has no follower command (recorded before the command topic existed): purpose says what
    it was needed for."""
    feats = features if features is not None else recording_features(ep.recording)
    state = np.concatenate([feature_on_grid(ep, feats[f"{arm}.{k}"], grid) for k in POLICY_STATE], 1)
    acts = [feats[f"{action_of(arm)}.{k}"] for k in POLICY_STATE]
    topic = acts[0].topic
    if topic not in ep.recording.topics or len(ep.topic(topic)) < 2:
        raise UserError(f"episode {episode_id(ep)} has no follower command ({topic}): no action to {purpose}",
                        where=str(ep.recording.path),
                        fix="record with `factr2 teleop --record` (factr2 >= the follower-command topic)")
    action = np.concatenate([feature_on_grid(ep, f, grid) for f in acts], 1)
    return state, action
