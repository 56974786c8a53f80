"""Decode a recording once into numpy arrays, and keep them in a cache folder (derived_dir: under the user's
cache folder, keyed by the recording's path).

Layout: manifest.json (key, topics, events, metadata, warnings) + one .npy per topic field and per camera
(timestamps and frame locations; JPEG bytes stay in the MCAP). The key is the MCAP's size, mtime_ns and a
SHA-256 of its first and last 64 KiB: any change (a recording still growing, a recover, a trim) rebuilds it.
The cache is written to a temporary folder and renamed into place, so a crash never leaves a half cache.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import tempfile
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from hardware.recording import schemas as S
from hardware.recording.mcap_scan import (
    ChannelRec,
    MessageRec,
    MetadataRec,
    RecordingError,
    ScanState,
    SchemaRec,
    iter_records,
    open_buffer,
)
from hardware.switches import switches

CACHE_VERSION = 1
_KEY_BLOCK = 64 * 1024


class LazyFields(Mapping):
    """field name -> array, each produced on first access (a cached recording reads only the fields used)."""

    def __init__(self, loaders: dict[str, Callable[[], np.ndarray]]):
        self._loaders, self._arrays = loaders, {}

    def __getitem__(self, key: str) -> np.ndarray:
        arr = self._arrays.get(key)
        if arr is None:
            arr = self._arrays[key] = self._loaders[key]()
        return arr

    def __iter__(self):
        return iter(self._loaders)

    def __len__(self) -> int:
        return len(self._loaders)


@dataclass
class TopicArrays:
    """One numeric topic: t [s] (rig clock, sorted) and one array per schema field (N, ...)."""

    topic: str
    schema: str
    t: np.ndarray
    fields: Mapping[str, np.ndarray]
    meta: dict[str, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass
class FrameIndex:
    """Where a camera's frames are: t [s], MCAP log_time [ns], loc (N, 3) (see mcap_scan.MessageRec)."""

    camera: str
    t: np.ndarray
    log_time: np.ndarray
    loc: np.ndarray


@dataclass
class Decoded:
    path: Path
    topics: dict[str, TopicArrays]
    frames: dict[str, FrameIndex]
    events: list[dict]
    metadata: dict[str, dict[str, str]]
    truncated: bool
    warnings: list[str]
    from_cache: bool = False

    @property
    def info(self) -> dict[str, str]:
        return self.metadata.get(S.RECORDING_METADATA, {})


def cache_home() -> Path:
    """factr2's folder for caches: $FACTR2_CACHE, default ~/.cache/factr2 (the demo's NEXT cache too)."""
    return switches().cache


def derived_dir(path: str | Path, kind: str) -> Path:
    """Where a cache derived from recording `path` lives: $FACTR2_RECORDING_CACHE (default
    cache_home()/recordings) / kind / <file name>-<hash of its absolute path>. Not beside the recording:
    the user's data folder holds only what they recorded (a collect folder once filled with FILE.factr2cache
    and FILE.policy-frames folders). The cache's own key (size, mtime, head/tail hash) still decides whether
    it matches the file."""
    p = Path(path).resolve()
    return switches().recording_cache / kind / f"{p.name}-{hashlib.sha256(str(p).encode()).hexdigest()[:12]}"


def cache_dir(path: str | Path) -> Path:
    return derived_dir(path, "arrays")


def cache_key(path: Path) -> dict:
    st = path.stat()
    h = hashlib.sha256()
    with open(path, "rb") as f:
        h.update(f.read(_KEY_BLOCK))
        if st.st_size > _KEY_BLOCK:
            f.seek(max(_KEY_BLOCK, st.st_size - _KEY_BLOCK))
            h.update(f.read(_KEY_BLOCK))
    return {"version": CACHE_VERSION, "size": st.st_size, "mtime_ns": st.st_mtime_ns,
            "head_tail_sha256": h.hexdigest()}


def _field_array(schema: S.Schema, f: S.Field, rows: list[dict], n: int) -> np.ndarray:
    vals = [r.get(f.name) for r in rows]
    if f.kind == "float":
        if f.vector:
            return np.array([v if v is not None else [] for v in vals], dtype=float).reshape(n, -1)
        return np.array([np.nan if v is None else v for v in vals], dtype=float)
    dtype = bool if f.kind == "bool" else np.int64
    return np.array([0 if v is None else v for v in vals], dtype=dtype).reshape((n, -1) if f.vector else (n,))


def decode(path: str | Path) -> Decoded:
    """Scan the MCAP front to back (truncation-tolerant) and turn every factr2 topic into arrays."""
    path = Path(path)
    buf, close = open_buffer(path)
    state = ScanState()
    try:
        schemas: dict[int, SchemaRec] = {}
        channels: dict[int, ChannelRec] = {}
        payloads: dict[int, list] = {}
        times: dict[int, list[int]] = {}
        locs: dict[int, list] = {}
        metadata: dict[str, dict[str, str]] = {}
        for rec in iter_records(buf, state):
            if isinstance(rec, MessageRec):
                ch = channels.get(rec.channel_id)
                if ch is None:
                    continue
                times[rec.channel_id].append(rec.log_time)
                if ch.encoding == "protobuf":
                    locs[rec.channel_id].append(rec.loc)
                else:
                    payloads[rec.channel_id].append(bytes(rec.data))
            elif isinstance(rec, ChannelRec):
                if rec.id not in channels:
                    channels[rec.id] = rec
                    payloads[rec.id], times[rec.id], locs[rec.id] = [], [], []
            elif isinstance(rec, SchemaRec):
                schemas[rec.id] = rec
            elif isinstance(rec, MetadataRec):
                name = rec.name if rec.name not in metadata else f"{rec.name}#{len(metadata)}"
                metadata[name] = rec.metadata
    finally:
        close()
    if S.RECORDING_METADATA not in metadata and state.profile != S.PROFILE:
        raise RecordingError(f"not a factr2 recording (MCAP profile {state.profile!r}, no factr2 recording "
                             "metadata)", where=str(path), fix="pass a file written by factr2 record/teleop")
    offset = float(metadata.get(S.RECORDING_METADATA, {}).get("clock_offset_s", "0") or 0)
    warn = list(state.warnings)
    topics: dict[str, TopicArrays] = {}
    frames: dict[str, FrameIndex] = {}
    events: list[dict] = []
    skipped = []
    for cid, ch in channels.items():
        sch = schemas.get(ch.schema_id)
        sname = sch.name if sch else ""
        lt = np.asarray(times[cid], dtype=np.int64)
        if ch.encoding == "protobuf" and sname == "foxglove.CompressedImage":
            order = np.argsort(lt, kind="stable")
            loc = np.asarray(locs[cid], dtype=np.int64).reshape(-1, 3)[order]
            cam = ch.metadata.get("camera") or S.camera_name(ch.topic)
            frames[cam] = FrameIndex(cam, S.rig_time_s(lt[order], offset), lt[order], loc)
            continue
        if ch.encoding != "json" or (sname not in S.NUMERIC_SCHEMAS and sname != S.EVENT_SCHEMA_NAME):
            skipped.append(ch.topic)
            continue
        try:
            rows = json.loads(b"[" + b",".join(payloads[cid]) + b"]")
        except ValueError as e:
            warn.append(f"topic {ch.topic}: undecodable JSON ({e}); topic skipped")
            continue
        if sname == S.EVENT_SCHEMA_NAME:
            for r, ns in zip(rows, lt.tolist()):
                t_ev = r.get("t")
                events.append({"t": float(S.rig_time_s(ns, offset) if t_ev is None else t_ev),
                               "kind": str(r.get("kind", "note")),
                               "episode": int(r.get("episode", -1)), "text": str(r.get("text", "")),
                               "value": float("nan") if r.get("value") is None else float(r["value"]),
                               "log_time": int(ns)})
            continue
        schema = S.NUMERIC_SCHEMAS[sname]
        n = len(rows)
        try:
            t = np.array([r.get("t", np.nan) for r in rows], dtype=float)
            fields = {f.name: _field_array(schema, f, rows, n) for f in schema.fields}
        except (ValueError, TypeError) as e:
            warn.append(f"topic {ch.topic}: inconsistent sample sizes ({e}); topic skipped")
            continue
        order = np.argsort(t, kind="stable")
        if not np.all(order == np.arange(n)):
            t = t[order]
            fields = {k: v[order] for k, v in fields.items()}
        topics[ch.topic] = TopicArrays(ch.topic, sname, t, fields, dict(ch.metadata))
    if skipped:
        warn.append(f"{len(skipped)} channel(s) with unknown schemas skipped: {', '.join(skipped[:5])}")
    events.sort(key=lambda e: (e["t"], e["log_time"]))
    return Decoded(path, topics, frames, events, metadata, state.truncated, warn)


def save(dec: Decoded, key: dict) -> Path | None:
    """Write the cache atomically; returns its folder, or None (with a warning) when it cannot be written."""
    final = cache_dir(dec.path)
    tmp = None
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        # unique per writer: two readers of one file (threads of one process too) may cache it at once
        tmp = Path(tempfile.mkdtemp(dir=final.parent, prefix=final.name + ".tmp-"))
        manifest = {"key": key, "truncated": dec.truncated, "warnings": dec.warnings, "events": dec.events,
                    "metadata": dec.metadata, "topics": {}, "frames": {}}
        for i, (name, ta) in enumerate(dec.topics.items()):
            stem = f"topic{i}"
            np.save(tmp / f"{stem}.t.npy", ta.t)
            for f, arr in ta.fields.items():
                np.save(tmp / f"{stem}.{f}.npy", arr)
            manifest["topics"][name] = {"stem": stem, "schema": ta.schema, "meta": ta.meta,
                                        "fields": list(ta.fields)}
        for i, (cam, fi) in enumerate(dec.frames.items()):
            stem = f"camera{i}"
            for part in ("t", "log_time", "loc"):
                np.save(tmp / f"{stem}.{part}.npy", getattr(fi, part))
            manifest["frames"][cam] = stem
        (tmp / "manifest.json").write_text(json.dumps(manifest))
        if final.exists():
            old = Path(tempfile.mkdtemp(dir=final.parent, prefix=final.name + ".old-"))
            try:
                final.rename(old / "cache")
            except FileNotFoundError:
                pass  # another writer replaced it meanwhile
            shutil.rmtree(old, ignore_errors=True)
        try:
            tmp.rename(final)
        except OSError:
            if not final.exists():
                raise
            shutil.rmtree(tmp, ignore_errors=True)  # another writer put an equal cache in place first
        return final
    except OSError as e:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        warnings.warn(f"{dec.path}: array cache not written ({e.strerror or e}); reading stays uncached",
                      stacklevel=3)
        return None


def load(path: Path, key: dict) -> Decoded | None:
    """The cached arrays when the cache matches `key`, else None."""
    d = cache_dir(path)
    try:
        manifest = json.loads((d / "manifest.json").read_text())
        if manifest.get("key") != key:
            return None
        topics = {}
        for name, m in manifest["topics"].items():
            stem = m["stem"]
            fields = LazyFields({f: partial(np.load, d / f"{stem}.{f}.npy") for f in m["fields"]})
            topics[name] = TopicArrays(name, m["schema"], np.load(d / f"{stem}.t.npy"), fields, m["meta"])
        frames = {cam: FrameIndex(cam, *(np.load(d / f"{stem}.{p}.npy") for p in ("t", "log_time", "loc")))
                  for cam, stem in manifest["frames"].items()}
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return Decoded(path, topics, frames, manifest["events"], manifest["metadata"], manifest["truncated"],
                   manifest["warnings"], from_cache=True)


def load_or_decode(path: str | Path, *, use_cache: bool = True, write_cache: bool = True) -> Decoded:
    """Arrays of a recording: from its cache folder when it matches the file, else decoded (and cached)."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError("file not found", where=str(path), fix="check the path")
    key = cache_key(path)
    if use_cache:
        dec = load(path, key)
        if dec is not None:
            return dec
    dec = decode(path)
    if write_cache and cache_key(path) == key:  # do not cache a file that grew while we read it
        save(dec, key)
    return dec
