"""Which NEXT checkpoint: one identity, written and compared here only.

A checkpoint is the pair <path>.json + <path>.safetensors (calibration.next.checkpoint). Its identity is the
SHA-256 of the JSON (which names the weights file and holds the training metrics, so a retrain changes it);
the path only says where it was. One string form, "PATH@SHA12". Two older forms still parse, so recordings
and trained runs from before keep loading:
- "PATH#DATAHASH" (recording metadata): the first 12 hex digits of the checkpoint's training-data hash;
- "STEM@SHA12" (offline labelling): the file's stem instead of its path (the new form with a short path).
A checkpoint read from disk (NextId.of) carries both digests, so it compares equal to an id in either form.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path

DIGITS = 12  # hex digits of a digest an id keeps
_SHA_FORM = re.compile(rf"^(?P<path>.*)@(?P<sha>[0-9a-f]{{{DIGITS}}})$")
_DATA_FORM = re.compile(r"^(?P<path>.*)#(?P<data>[0-9a-f]+)$")  # older recordings' "PATH#DATAHASH"


def json_path(path: str | Path) -> Path:
    """A checkpoint's JSON file, whichever of its names is given (PATH, PATH.json, PATH.safetensors)."""
    return Path(path).with_suffix(".json")


@dataclass(frozen=True, eq=False)
class NextId:
    """A NEXT checkpoint's identity. path: where it was (legacy offline ids: the file's stem); sha256: the
    first DIGITS hex digits of the SHA-256 of its JSON; data_hash: the first DIGITS of its training-data hash
    (legacy "PATH#DATAHASH" ids carry only this one).

    Equality is "the same NEXT": equal sha256 when both have one, else equal data_hash when both have one,
    else not the same (an id without a digest names no checkpoint for sure: it matches none, itself
    included). Not hashable for that reason: key a dict by str(id)."""

    path: str
    sha256: str = ""
    data_hash: str = ""

    @classmethod
    def of(cls, path: str | Path) -> NextId:
        """The id of the checkpoint at `path` as it is on disk now (no digest when its JSON is not there or
        not readable)."""
        p = json_path(path)
        if not p.is_file():
            return cls(str(path))
        raw = p.read_bytes()
        try:
            data = str(json.loads(raw).get("data_hash", "") or "")[:DIGITS]
        except (ValueError, AttributeError):
            data = ""
        return cls(str(path), hashlib.sha256(raw).hexdigest()[:DIGITS], data)

    @classmethod
    def parse(cls, text: str) -> NextId:
        """An id from its string form, or from either older form (module docstring). Any other text is a path
        without a digest."""
        text = str(text).strip()
        m = _SHA_FORM.match(text)
        if m:
            return cls(m["path"], sha256=m["sha"])
        m = _DATA_FORM.match(text)
        if m:
            return cls(m["path"], data_hash=m["data"][:DIGITS])
        return cls(text)

    def __str__(self) -> str:
        if self.sha256:
            return f"{self.path}@{self.sha256}"
        return f"{self.path}#{self.data_hash}" if self.data_hash else self.path

    @property
    def short(self) -> str:
        """For messages: the file's stem and the digest ("next@1a2b3c4d5e6f")."""
        name = json_path(self.path).stem if self.path else "?"
        return str(NextId(name, self.sha256, self.data_hash))

    def __eq__(self, other) -> bool:
        if not isinstance(other, NextId):
            return NotImplemented
        if self.sha256 and other.sha256:
            return self.sha256 == other.sha256
        if self.data_hash and other.data_hash:
            return self.data_hash == other.data_hash
        return False

    __hash__ = None  # equality is not an equivalence on every field (see the class docstring)

    def matches(self, path: str | Path) -> bool:
        """Whether the checkpoint at `path` is the one this id names."""
        return self == NextId.of(path)

    def located(self) -> Path | None:
        """The JSON of the checkpoint where the id says it was, when that is the same NEXT; else None."""
        p = json_path(self.path) if self.path else None
        return p if p is not None and p.is_file() and self.matches(p) else None


def parse_ids(text: str | None) -> tuple[NextId, ...]:
    """The ids a recording or a run names: "" for none, several comma-separated (one per arm running NEXT)."""
    return tuple(NextId.parse(part) for part in str(text or "").split(",") if part.strip())


def format_ids(ids) -> str:
    """The one string form of several ids (parse_ids reads it back)."""
    return ",".join(str(i) for i in ids)
