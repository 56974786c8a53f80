"""One NEXT identity (calibration.next.ident): the string form round-trips, both older forms still parse and
compare with the checkpoint on disk, and a rollout refuses a policy whose NEXT is not the one here."""

from __future__ import annotations

import hashlib
import json

import pytest

from calibration.next.ident import NextId, format_ids, parse_ids
from factr2_teleop.session.rollout import NextNote, resolve_next
from hardware.errors import UserError


def _checkpoint(path, data_hash="abcdef0123456789", metrics=0.05):
    path.write_text(json.dumps({"data_hash": data_hash, "metrics": {"val_l1": [metrics]}}))
    return path, hashlib.sha256(path.read_bytes()).hexdigest()[:12]


def test_the_string_form_round_trips(tmp_path):
    ck, sha = _checkpoint(tmp_path / "next.json")
    ident = NextId.of(ck)
    assert (ident.sha256, ident.data_hash) == (sha, "abcdef012345")
    assert str(ident) == f"{ck}@{sha}"
    back = NextId.parse(str(ident))
    assert back == ident and back.path == str(ck) and str(back) == str(ident)
    assert parse_ids(format_ids([ident, ident])) == (ident, ident)  # one per arm
    assert parse_ids("") == () and parse_ids(None) == ()
    assert ident.short == f"next@{sha}"


def test_both_legacy_forms_still_name_the_checkpoint(tmp_path):
    ck, sha = _checkpoint(tmp_path / "next.json")
    session = NextId.parse(f"{ck.with_suffix('')}#abcdef012345")  # sessions: PATH#DATAHASH
    offline = NextId.parse(f"next@{sha}")  # offline labelling: STEM@SHA
    assert session.data_hash == "abcdef012345" and not session.sha256
    assert offline.path == "next" and offline.sha256 == sha
    assert session == NextId.of(ck) and offline == NextId.of(ck)
    assert session.matches(ck) and offline.matches(ck)
    assert str(session) == f"{ck.with_suffix('')}#abcdef012345"  # read back as written
    assert session.located() == ck and offline.located() is None  # a stem does not say where it is
    # a path with the separators in it: only a trailing digest counts
    odd = NextId.parse(f"{tmp_path}/a@b#c/next@{sha}")
    assert odd.path == f"{tmp_path}/a@b#c/next" and odd.sha256 == sha


def test_a_different_checkpoint_is_not_the_same_next(tmp_path):
    ck, _ = _checkpoint(tmp_path / "next.json")
    other, _ = _checkpoint(tmp_path / "other.json", data_hash="abcdef0123456789", metrics=0.07)
    assert NextId.of(ck) != NextId.of(other)  # same training data, another model: not the same NEXT
    assert NextId.parse(f"{ck}#000000000000") != NextId.of(ck)
    assert not NextId.parse("next@000000000000").matches(ck)
    unknown = NextId.parse("?")
    assert unknown != unknown and not unknown.matches(ck)  # no digest names no checkpoint for sure
    with pytest.raises(TypeError):
        hash(NextId.of(ck))  # equality is not per field: never a dict key by accident


def test_rollout_refuses_a_policy_whose_next_is_gone_or_changed(tmp_path):
    ck, sha = _checkpoint(tmp_path / "next.json")
    meta = {"next_checkpoint": str(NextId.of(ck))}
    assert resolve_next(meta, None) == (ck, None)
    ck.write_text(ck.read_text() + " ")  # changed in place: another file, not the trained NEXT
    with pytest.raises(UserError, match="not here"):
        resolve_next(meta, None)
    path, note = resolve_next(meta, ck)  # --next asks for it anyway: used, and said
    assert path == ck and note.kind is NextNote.NOT_TRAINED_WITH and f"@{sha}" in str(note)
    with pytest.raises(UserError, match="several arms"):
        resolve_next({"next_checkpoint": format_ids([NextId.of(ck)] * 2)}, None)
