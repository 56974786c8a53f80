"""Rewrite a truncated or damaged MCAP (recorder killed, disk full, power loss) into a valid, indexed file.

Every complete record is kept (schemas, channels, messages, metadata); damaged chunks are skipped and
reported. The result has a summary, so any MCAP tool (Foxglove, mcap CLI) opens it.
Also the engine of episodes.py's rewrites: `rewrite(src, dst, keep=..., transform=...)`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from hardware.recording.mcap_scan import (
    ChannelRec,
    MessageRec,
    MetadataRec,
    RecordingError,
    ScanState,
    SchemaRec,
    iter_records,
    open_buffer,
    read_header,
)


@dataclass
class RewriteReport:
    src: Path
    dst: Path
    messages: int = 0
    dropped: int = 0
    metadata: int = 0
    was_truncated: bool = False
    lost_bytes: int = 0
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> str:
        s = f"{self.src} -> {self.dst}: {self.messages} messages kept"
        if self.dropped:
            s += f", {self.dropped} removed"
        if self.was_truncated:
            s += f" (source was truncated: last {self.lost_bytes} bytes were an incomplete record)"
        return s


# keep(topic, log_time_ns, data) -> bool;  transform(topic, schema_name, log_time_ns, data) -> (ns, data)
KeepFn = Callable[[str, int, bytes], bool]
TransformFn = Callable[[str, str, int, bytes], "tuple[int, bytes]"]


class _Out:
    """Writes records of one or more sources into one MCAP, remapping schema/channel ids."""

    def __init__(self, dst: Path, profile: str, library: str):
        from mcap.writer import CompressionType, Writer

        self.f = open(dst, "wb")
        self.w = Writer(self.f, chunk_size=1024 * 1024, compression=CompressionType.ZSTD)
        self.w.start(profile=profile, library=library or "factr2")
        self.schema_ids: dict[tuple, int] = {}
        self.channel_ids: dict[tuple, int] = {}

    def add_source(self, buf, state: ScanState, report: RewriteReport, keep: KeepFn | None,
                   transform: TransformFn | None, meta_fn: Callable[[str, dict], dict | None] | None = None):
        schemas: dict[int, SchemaRec] = {}
        channels: dict[int, tuple[ChannelRec, int, str]] = {}
        for rec in iter_records(buf, state):
            if isinstance(rec, MessageRec):
                ch = channels.get(rec.channel_id)
                if ch is None:
                    report.dropped += 1
                    continue
                chan, out_id, sname = ch
                data = bytes(rec.data)
                if keep is not None and not keep(chan.topic, rec.log_time, data):
                    report.dropped += 1
                    continue
                ns = rec.log_time
                if transform is not None:
                    ns, data = transform(chan.topic, sname, ns, data)
                self.w.add_message(out_id, ns, data, ns, rec.sequence)
                report.messages += 1
            elif isinstance(rec, SchemaRec):
                schemas[rec.id] = rec
            elif isinstance(rec, ChannelRec):
                sch = schemas.get(rec.schema_id)
                skey = (sch.name, sch.encoding, sch.data) if sch else None
                sid = 0
                if skey is not None:
                    if skey not in self.schema_ids:
                        self.schema_ids[skey] = self.w.register_schema(*skey)
                    sid = self.schema_ids[skey]
                ckey = (rec.topic, rec.encoding, sid)
                if ckey not in self.channel_ids:
                    self.channel_ids[ckey] = self.w.register_channel(rec.topic, rec.encoding, sid,
                                                                     rec.metadata)
                channels[rec.id] = (rec, self.channel_ids[ckey], sch.name if sch else "")
            elif isinstance(rec, MetadataRec):
                meta = meta_fn(rec.name, rec.metadata) if meta_fn else rec.metadata
                if meta is not None:
                    self.w.add_metadata(rec.name, meta)
                    report.metadata += 1
        report.was_truncated = report.was_truncated or state.truncated
        report.lost_bytes += max(0, state.size - state.valid_bytes) if state.truncated else 0
        report.warnings += [w for w in state.warnings if "truncated" not in w]

    def finish(self):
        self.w.finish()
        self.f.flush()
        os.fsync(self.f.fileno())
        self.f.close()


def rewrite(src: str | Path, dst: str | Path, *, keep: KeepFn | None = None,
            transform: TransformFn | None = None) -> RewriteReport:
    """Copy src's complete records into a new valid MCAP dst (dst written to a temporary name first)."""
    src, dst = Path(src), Path(dst)
    report = RewriteReport(src, dst)
    buf, close = open_buffer(src)
    state = ScanState()
    tmp = dst.with_name(dst.name + f".tmp-{os.getpid()}")
    try:
        out = _Out(tmp, *read_header(buf))  # the output keeps the source's profile
        try:
            out.add_source(buf, state, report, keep, transform)
            out.finish()
        except BaseException:
            out.f.close()
            raise
        os.replace(tmp, dst)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise RecordingError(f"cannot write {dst} ({e.strerror or e})", where=str(src),
                             fix="check free space and permissions") from None
    finally:
        close()
    return report


RECOVERED = ".recovered.mcap"


def recovered_path(src: str | Path) -> Path:
    """Where `factr2 recover FILE` writes by default: FILE's stem + ".recovered.mcap", beside it."""
    src = Path(src)
    return src.with_name(src.stem + RECOVERED)


def drop_superseded(files: list[Path]) -> list[Path]:
    """The files without those a recovered copy in the same list replaces: a damaged X.mcap beside its
    X.recovered.mcap would list (and train on) every episode twice. Order kept."""
    have = {Path(f) for f in files}
    return [f for f in files if not (Path(f).suffix == ".mcap" and not Path(f).name.endswith(RECOVERED)
                                     and recovered_path(f) in have)]


def recover(src: str | Path, dst: str | Path | None = None, *, in_place: bool = False) -> RewriteReport:
    """Make a valid MCAP from a truncated/damaged one. Default output: SRC with ".recovered.mcap";
    in_place=True replaces SRC atomically (only after the new file is complete)."""
    src = Path(src)
    if in_place:
        dst = src
    elif dst is None:
        dst = recovered_path(src)
    return rewrite(src, dst)
