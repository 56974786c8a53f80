"""Episode management: list, show, trim, delete, merge (pure functions; the CLI is a thin shell).

Safe against half-written files: listing reads truncated files (marked "truncated"), unreadable files become
a row with an error instead of an exception, and rewrites refuse a file a Recorder still holds (flock) and
replace the original only after the new file is complete (write to a temporary name, then rename).
"""

from __future__ import annotations

import fcntl
import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hardware.errors import UserError
from hardware.recording import schemas as S
from hardware.recording.mcap_scan import ScanState, open_buffer, read_header
from hardware.recording.protobuf_wire import decode_compressed_image, encode_compressed_image
from hardware.recording.reader import UNMARKED, Recording
from hardware.recording.recover import RewriteReport, _Out, rewrite


@dataclass
class EpisodeRow:
    """One line of `factr2 episodes list`. duration_s [s]; contact_share in [0, 1] (NaN: no contact data)."""

    file: Path
    index: int
    outcome: str
    task: str = ""
    t_start: float = float("nan")
    duration_s: float = float("nan")
    samples: int = 0
    contact_share: float = float("nan")
    truncated: bool = False
    error: str = ""


def _files(path: Path) -> list[Path]:
    if path.is_dir():
        from hardware.recording.recover import drop_superseded

        files = sorted(p for p in path.iterdir()
                       if p.is_file() and p.suffix in (".mcap", ".npz") and ".tmp-" not in p.name)
        return drop_superseded(files)  # a damaged file beside its recovered copy is listed once, as the copy
    if not path.exists():
        raise UserError("no such file or folder", where=str(path), fix="check the path")
    return [path]


def list_episodes(path: str | Path) -> list[EpisodeRow]:
    """Rows for every episode of every .mcap recording and .npz plain log in a folder (or one file)."""
    rows: list[EpisodeRow] = []
    for f in _files(Path(path)):
        try:
            if f.suffix == ".npz":
                from hardware.recording.plain_log import load_plain_log

                log = load_plain_log(f)
                share = float(np.mean(log.contact)) if log.contact is not None else float("nan")
                rows.append(EpisodeRow(f, 0, "plain log", "", float(log.t[0]), log.duration_s, len(log.t),
                                       share))
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                rec = Recording(f)
            arm = "follower" if S.joint_state_topic("follower") in rec.topics else "leader"
            for ep in rec.episodes:
                js = S.joint_state_topic(arm)
                n = len(ep.topic(js)) if js in rec.topics else 0
                rows.append(EpisodeRow(f, ep.index, ep.outcome, ep.task, ep.t_start, ep.duration_s, n,
                                       ep.contact_share(arm), rec.truncated))
        except UserError as e:
            rows.append(EpisodeRow(f, -1, "unreadable", error=str(e)))
    return rows


def format_rows(rows: list[EpisodeRow]) -> str:
    head = f"{'file':<32} {'ep':>3} {'outcome':<11} {'duration':>9} {'samples':>8} {'contact':>8}  task"
    out = [head]
    for r in rows:
        if r.error:
            out.append(f"{r.file.name:<32} {'-':>3} {r.outcome:<11} {r.error}")
            continue
        contact = "-" if np.isnan(r.contact_share) else f"{100 * r.contact_share:.0f}%"
        flag = " [truncated: factr2 recover]" if r.truncated else ""
        out.append(f"{r.file.name:<32} {r.index:>3} {r.outcome:<11} {r.duration_s:>8.2f}s {r.samples:>8} "
                   f"{contact:>8}  {r.task}{flag}")
    good = [r for r in rows if not r.error]
    total = sum(r.duration_s for r in good if np.isfinite(r.duration_s))
    n_ok = sum(r.outcome == "success" for r in good)
    out.append(f"{len(good)} episode(s), {total:.1f} s, {n_ok} success, "
               f"{sum(r.outcome == 'failure' for r in good)} failure, {len(rows) - len(good)} unreadable")
    if any(np.isfinite(r.contact_share) for r in good):
        # collect's summary and `episodes phases` count FIRST's contact phase instead: another threshold
        out.append("contact: share of samples the live estimator flagged in contact (teleop's feedback "
                   "gate); FIRST's contact phase (`episodes phases`, collect's summary) uses the "
                   "recordings' own thresholds and differs")
    return "\n".join(out)


def show(path: str | Path) -> str:
    """A recording's metadata, topics (counts and rates), cameras, episodes and events (an operator's
    interventions in a rollout included), as text."""
    from hardware.recording.interventions import describe as describe_interventions

    if Path(path).suffix == ".npz":
        from hardware.recording.plain_log import load_plain_log

        log = load_plain_log(path)
        extra = [k for k in ("temperature", "tau_ext_true", "force", "contact")
                 if getattr(log, k) is not None]
        return (f"{log.path}  plain log: {len(log.t)} samples, {log.duration_s:.2f} s, {log.n_joints} "
                f"joints ({', '.join(log.joint_names)}), torque in {log.units}; "
                f"optional: {', '.join(extra) or 'none'}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = Recording(path)
    s = rec.info
    lines = [f"{rec.path}  ({rec.path.stat().st_size / 1e6:.1f} MB){'  TRUNCATED' if rec.truncated else ''}"]
    for k in ("start_time", "time_zone", "operator", "software_version", "simulated", "next_checkpoint",
              "task",
              "rig_file", "arm_description_sha256"):
        if s.get(k):
            lines.append(f"  {k}: {s[k]}")
    lines.append("topics:")
    for name in rec.topics:
        ta = rec.topic(name)
        span = ta.t[-1] - ta.t[0] if len(ta) > 1 else 0.0
        rate = (len(ta) - 1) / span if span > 0 else 0.0
        lines.append(f"  {name:<28} {ta.schema:<22} {len(ta):>8} msgs  {rate:8.1f} Hz")
    for cam in rec.cameras:
        fr = rec.frames(cam)
        span = fr.t[-1] - fr.t[0] if len(fr) > 1 else 0.0
        rate = (len(fr) - 1) / span if span else 0.0
        lines.append(f"  camera {cam:<21} {'jpeg':<22} {len(fr):>8} frames {rate:6.1f} Hz")
    lines.append("episodes:")
    for ep in rec.episodes:
        lines.append(f"  {ep.index:>3} {ep.outcome:<11} {ep.t_start:10.3f} .. {ep.t_stop:10.3f} s "
                     f"({ep.duration_s:.2f} s) {ep.task}")
        for t, v, label in ep.progress:
            lines.append(f"        progress {v:.2f} at {t:.3f} s {label}")
        for note in ep.notes:
            lines.append(f"        note: {note}")
        lines += [f"        {line}" for line in describe_interventions(ep)]
    lines += [f"warning: {w.message}" for w in caught]
    return "\n".join(lines)


def _check_not_recording(path: Path) -> None:
    with open(path, "rb") as f:
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)
        except OSError:
            raise UserError("file is being recorded right now", where=str(path),
                            fix="stop the recording first") from None


def _episode(rec: Recording, index: int):
    for ep in rec.episodes:
        if ep.index == index and ep.outcome != UNMARKED:
            return ep
    have = [e.index for e in rec.episodes if e.outcome != UNMARKED]
    raise UserError(f"no episode {index}", where=str(rec.path),
                    fix=f"episodes in this file: {have}" if have else "this file has no episode events")


def _span_ns(rec: Recording, ep) -> tuple[int, int]:
    evs = [e for e in ep.events if e["kind"] in ("start", "stop")]
    lo = min(e["log_time"] for e in evs)
    hi = max(e["log_time"] for e in evs) if any(e["kind"] == "stop" for e in evs) else 2**63
    return lo, hi


def delete_episode(path: str | Path, index: int, out: str | Path | None = None) -> RewriteReport:
    """Remove episode `index` (its messages between start and stop, and its events). In place by default."""
    path = Path(path)
    _check_not_recording(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = Recording(path)
    lo, hi = _span_ns(rec, _episode(rec, index))

    def keep(topic: str, ns: int, data: bytes) -> bool:
        if topic == S.TOPIC_EVENTS:
            return json.loads(data).get("episode") != index
        return not lo <= ns <= hi

    return rewrite(path, out or path, keep=keep)


def trim_episode(path: str | Path, index: int, start_s: float = 0.0, end_s: float | None = None,
                 out: str | Path | None = None) -> RewriteReport:
    """Keep only [start_s, end_s] [s, relative to the episode's start] of episode `index`."""
    path = Path(path)
    _check_not_recording(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = Recording(path)
    ep = _episode(rec, index)
    t0 = ep.t_start + max(0.0, float(start_s))
    t1 = ep.t_stop if end_s is None else min(ep.t_stop, ep.t_start + float(end_s))
    if t1 <= t0:
        raise UserError(f"empty trim window {start_s}..{end_s} s", where=str(path),
                        fix=f"episode {index} lasts {ep.duration_s:.2f} s")
    offset = float(rec.info.get("clock_offset_s", 0) or 0)
    lo, hi = _span_ns(rec, ep)
    n0, n1 = S.log_time_ns(t0, offset), S.log_time_ns(t1, offset)

    def keep(topic: str, ns: int, data: bytes) -> bool:
        return topic == S.TOPIC_EVENTS or not (lo <= ns <= hi) or n0 <= ns <= n1

    def transform(topic: str, schema: str, ns: int, data: bytes) -> tuple[int, bytes]:
        if topic == S.TOPIC_EVENTS:
            ev = json.loads(data)
            if ev.get("episode") == index and ev.get("kind") in ("start", "stop"):
                t = t0 if ev["kind"] == "start" else t1
                ev["t"] = t
                return S.log_time_ns(t, offset), json.dumps(ev).encode()
        return ns, data

    return rewrite(path, out or path, keep=keep, transform=transform)


def _shifter(shift_s: float, delta_ns: int, episode_offset: int):
    def transform(topic: str, schema: str, ns: int, data: bytes) -> tuple[int, bytes]:
        if delta_ns == 0 and episode_offset == 0:
            return ns, data
        if schema == "foxglove.CompressedImage":
            stamp, img, fmt, frame_id = decode_compressed_image(data)
            return ns + delta_ns, encode_compressed_image(stamp + delta_ns, bytes(img), fmt, frame_id)
        d = json.loads(data)
        d["t"] = float(d.get("t", 0.0)) + shift_s
        if topic == S.TOPIC_EVENTS:
            d["episode"] = int(d.get("episode", -1)) + episode_offset
        return ns + delta_ns, S.encode_json(d)

    return transform


def merge(paths: list[str | Path], out: str | Path) -> RewriteReport:
    """Concatenate recordings into `out`; episodes renumbered in order. A source whose time span overlaps the
    previous one (e.g. two simulated sessions both starting at t = 0) is shifted to start 1 s after it; the
    shifts are stored in the "factr2.merge" metadata record."""
    files = [f for p in paths for f in _files(Path(p)) if f.suffix == ".mcap"]
    out = Path(out)
    if len(files) < 2:
        raise UserError(f"merge needs at least 2 .mcap files, got {len(files)}", fix="list files or a folder")
    if out.exists():
        raise UserError("output exists", where=str(out), fix="choose a new output name")
    recs = []
    for f in files:
        _check_not_recording(f)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            recs.append(Recording(f))
    offset0 = float(recs[0].info.get("clock_offset_s", 0) or 0)
    report = RewriteReport(files[0], out)
    tmp = out.with_name(out.name + ".tmp-merge")
    buf0, close0 = open_buffer(files[0])
    writer = _Out(tmp, *read_header(buf0))
    close0()
    prev_end, ep_offset, shifts = -np.inf, 0, []
    try:
        for f, rec in zip(files, recs):
            t_a, t_b = rec.time_span()
            shift = 0.0 if not np.isfinite(prev_end) or t_a > prev_end else prev_end + 1.0 - t_a
            own = float(rec.info.get("clock_offset_s", 0) or 0)
            delta_ns = S.offset_ns(offset0) - S.offset_ns(own) + round(shift * 1e9)
            shifts.append({"file": str(f), "shift_s": shift, "episode_offset": ep_offset})
            buf, close = open_buffer(f)
            try:
                writer.add_source(buf, ScanState(), report, None, _shifter(shift, delta_ns, ep_offset))
            finally:
                close()
            prev_end = t_b + shift
            ep_offset += max([e.index for e in rec.episodes if e.outcome != UNMARKED], default=-1) + 1
        writer.w.add_metadata("factr2.merge", {"sources": json.dumps(shifts)})
        writer.finish()
        tmp.rename(out)
    except BaseException:
        writer.f.close()
        tmp.unlink(missing_ok=True)
        raise
    return report
