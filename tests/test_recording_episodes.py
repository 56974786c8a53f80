"""Episode management: list (with .npz logs and unreadable files), show, trim, delete, merge; CLI."""

from __future__ import annotations

import fcntl

import numpy as np
import pytest
from recording_helpers import record_session

from factr2_teleop.cli import main as cli_main
from hardware.errors import UserError
from hardware.recording import Recording
from hardware.recording import episodes as E
from hardware.recording.plain_log import save_plain_log


@pytest.fixture
def session(tmp_path):
    path = tmp_path / "rec" / "a.mcap"
    path.parent.mkdir()
    record_session(path, n=500, episodes=3).close()
    return path


def test_list_counts_durations_outcomes_and_contact(session, tmp_path, capsys):
    folder = session.parent
    t = np.linspace(0, 1, 11)
    z = np.zeros((11, 2))
    save_plain_log(folder / "log.npz", t=t, q=z, qd=z, q_cmd=z, tau_m=z, contact=t > 0.5)
    (folder / "junk.mcap").write_bytes(b"garbage")
    (folder / "half.mcap").write_bytes(session.read_bytes()[:60_000])
    rows = E.list_episodes(folder)
    mine = [r for r in rows if r.file.name == "a.mcap"]
    assert [r.outcome for r in mine] == ["success", "failure", "success"]
    assert all(abs(r.duration_s - 0.5) < 1e-9 and r.samples == 500 for r in mine)
    assert abs(mine[0].contact_share - 0.3) < 0.01  # estimated contact on 30 of every 100 ticks
    npz = next(r for r in rows if r.file.name == "log.npz")
    assert npz.outcome == "plain log" and abs(npz.contact_share - 5 / 11) < 1e-9
    assert next(r for r in rows if r.file.name == "junk.mcap").error
    half = [r for r in rows if r.file.name == "half.mcap"]
    assert half and half[-1].truncated and half[-1].outcome == "incomplete"
    assert cli_main(["episodes", "list", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "truncated" in out and "2 success, 1 failure, 1 unreadable" in out
    assert cli_main(["episodes", "show", str(session)]) == 0
    out = capsys.readouterr().out
    assert "/follower/joint_state" in out and "camera wrist" in out and "progress 0.50" in out


def test_delete_and_trim(session, tmp_path):
    out = tmp_path / "deleted.mcap"
    E.delete_episode(session, 1, out)
    rec = Recording(out)
    assert [e.index for e in rec.episodes] == [0, 2]
    assert len(rec.topic("/follower/joint_state")) == 1000  # the other two episodes stay whole
    E.trim_episode(out, 2, start_s=0.1, end_s=0.3)  # in place
    rec = Recording(out)
    ep = rec.episodes[1]
    assert abs(ep.t_start - 1.3) < 1e-9 and abs(ep.duration_s - 0.2) < 1e-9 and ep.outcome == "success"
    assert len(ep.topic("/follower/joint_state")) == 201
    assert len(rec.episodes[0].topic("/follower/joint_state")) == 500  # other episodes untouched
    with pytest.raises(UserError, match="no episode 7"):
        E.delete_episode(out, 7)
    with pytest.raises(UserError, match="empty trim window"):
        E.trim_episode(out, 0, 0.4, 0.2)


def test_merge_shifts_overlapping_sessions(session, tmp_path):
    other = tmp_path / "b.mcap"
    record_session(other, n=300, episodes=1).close()  # also starts at t = 0 (simulated clock)
    out = tmp_path / "merged.mcap"
    E.merge([session, other], out)
    rec = Recording(out)
    eps = rec.episodes
    assert [e.index for e in eps] == [0, 1, 2, 3]
    assert eps[3].t_start > eps[2].t_stop and abs(eps[3].duration_s - 0.3) < 1e-6
    js = rec.topic("/follower/joint_state")
    assert len(js) == 1500 + 300 and np.all(np.diff(js.t) > 0)
    assert len(eps[3].frames("wrist")) == 10
    with pytest.raises(UserError, match="output exists"):
        E.merge([session, other], out)


def test_rewrites_refuse_a_file_being_recorded(session):
    with open(session, "rb") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        with pytest.raises(UserError, match="being recorded"):
            E.delete_episode(session, 0)
