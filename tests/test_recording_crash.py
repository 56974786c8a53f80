"""Crash safety: SIGKILL mid-episode loses at most 0.5 s; truncated, corrupt, empty and foreign files;
write errors stop the recorder cleanly."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from recording_helpers import record_session

from factr2_teleop.cli import main as cli_main
from hardware.recording import Recorder, Recording, RecordingError
from hardware.recording.recover import recover

REPO = Path(__file__).resolve().parents[1]
MIN_IMAGES = 15  # images the child hands over before it is killed (one every 33 samples)
FLUSH_S = 0.5  # s: what a SIGKILL of both may lose: twice the writer's flush interval (Recorder's 0.25 s)

CHILD = r"""
import sys, time
import numpy as np
from hardware.recording import Recorder
from hardware.types import JointState
rec = Recorder(sys.argv[1], joint_names={"follower": list("abcdef")}, t0=time.monotonic())
print("writer", rec._proc.pid, flush=True)
s = JointState.empty(6)
frame = np.zeros((48, 64, 3), np.uint8)
t = time.monotonic()
rec.start_episode(t, "crash test")
k = 0
while True:
    t = time.monotonic()
    s.q[:] = k
    rec.log_joint_state("follower", t, s)
    if k % 33 == 0:
        rec.log_image("cam", t, frame.copy())
    if k % 10 == 0:  # so far: time, images handed to the recorder, images its writer has written
        print(repr(t), k // 33 + 1, rec.status().frames_written, flush=True)
    k += 1
    time.sleep(0.001)
"""


def _record_then_kill(path: Path, kill_writer: bool) -> tuple[float, int, list]:
    """Run CHILD for ~1.5 s, at least MIN_IMAGES images (a slow machine runs fewer of its 1 ms steps a
    second, #53) and until its writer has written, an image too a flush interval ago (its JPEG encoding
    lags on a slow core); SIGKILL it (and its writer process when kill_writer), wait until the writer is
    gone. Returns (the last time the child handed over [s], the writer's pid, [(time, images handed,
    images written)])."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True,
                            env=env)
    writer = int(proc.stdout.readline().split()[1])
    last = []

    def reader():
        for line in proc.stdout:
            t, n, w = line.split()
            last.append((float(t), int(n), int(w)))

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    deadline = time.monotonic() + 60
    # the writer process must be up and have flushed data past its file's header (it imports for seconds on
    # a slow or busy machine)
    header = None
    while time.monotonic() < deadline:
        size = path.stat().st_size if path.exists() else 0
        header = header or size or None
        ran = bool(last) and last[-1][0] - last[0][0] >= 1.5 and last[-1][1] >= MIN_IMAGES
        if ran and header and size > header and _count_before(last, last[-1][0] - FLUSH_S - _stall(last), 2):
            break
        time.sleep(0.05)
    assert last, "child never started recording"
    if kill_writer:
        os.kill(writer, signal.SIGKILL)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    th.join(5)
    deadline = time.monotonic() + 30
    while Path(f"/proc/{writer}").exists() and time.monotonic() < deadline:  # (a zombie until reaped by init)
        if Path(f"/proc/{writer}/stat").read_text().split(")")[1].split()[0] == "Z":
            break
        time.sleep(0.02)
    return max(row[0] for row in last), writer, last


def _count_before(handed: list, t: float, col: int = 1) -> int:
    """Images the child had handed over (col 1) or its writer had written (col 2) by time t [s]."""
    return max((row[col] for row in handed if row[0] <= t), default=0)


def _stall(handed: list) -> float:
    """The longest this machine left the child unscheduled while it ran [s] (a busy or slow machine leaves
    the writer so too: its flush comes that much later, #53; ~0 when quiet)."""
    return max(0.0, float(np.max(np.diff([row[0] for row in handed]))) - 0.011) if len(handed) > 1 else 0.0


def _independent_count(path: Path, topic: str) -> int:
    """Messages on `topic` by the mcap library's own reader (its summary), not ours."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return summary.statistics.channel_message_counts[
        next(c.id for c in summary.channels.values() if c.topic == topic)]


def test_sigkill_of_the_app_loses_nothing_the_writer_finishes_the_file(tmp_path):
    """The writer process outlives the app: it drains the rings and writes the summary."""
    path = tmp_path / "killed.mcap"
    t_handed, _, handed = _record_then_kill(path, kill_writer=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # complete: no "truncated" warning
        rec = Recording(path, use_cache=False)
    js = rec.topic("/follower/joint_state")
    print(f"SIGKILL of the app lost {t_handed - js.t[-1]:.3f} s of joint states")
    assert t_handed - js.t[-1] <= 0.01  # all that was handed over (the last print may trail one sample)
    assert not rec.truncated
    assert rec.episodes[0].outcome == "incomplete" and rec.episodes[0].task == "crash test"
    assert len(rec.frames("cam")) >= _count_before(handed, t_handed)  # every image handed over
    assert _independent_count(path, "/follower/joint_state") == len(js)
    assert rec.metadata.get("factr2.recorder_stats", {}).get("ended") == "producer ended without closing"


def test_sigkill_of_app_and_writer_loses_at_most_the_flush_interval(tmp_path):
    path = tmp_path / "killed.mcap"
    t_handed, _, handed = _record_then_kill(path, kill_writer=True)
    assert path.stat().st_size > 0
    with pytest.warns(UserWarning, match="truncated"):
        rec = Recording(path, use_cache=False)
    t_last = rec.topic("/follower/joint_state").t[-1]
    # the flush interval, plus the longest this machine left the child unscheduled while it ran
    stall = _stall(handed)
    print(f"SIGKILL of both lost {t_handed - t_last:.3f} s of joint states (longest stall {stall:.3f} s)")
    assert t_handed - t_last <= FLUSH_S + stall, f"lost {t_handed - t_last:.3f} s"
    assert rec.truncated and rec.episodes[0].outcome == "incomplete" and rec.episodes[0].task == "crash test"
    # the images the writer had written (JPEG-encoded) before the last flush interval are in the file
    assert len(rec.frames("cam")) >= max(1, _count_before(handed, t_handed - FLUSH_S - stall, 2))
    report = recover(path)
    out = tmp_path / "killed.recovered.mcap"
    assert report.was_truncated and out.exists()
    n = len(rec.topic("/follower/joint_state"))
    assert _independent_count(out, "/follower/joint_state") == n  # a standard reader sees an indexed file
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec2 = Recording(out)
    assert not rec2.truncated and len(rec2.topic("/follower/joint_state")) == n


def test_truncated_file_reads_with_warning_and_cli_recovers(tmp_path, capsys):
    path = tmp_path / "s.mcap"
    record_session(path, n=3000, flush_interval_s=0.05, chunk_size=32 * 1024).close()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
    with pytest.warns(UserWarning, match="truncated"):
        rec = Recording(cut)
    n = len(rec.topic("/follower/joint_state"))
    assert 0 < n < 3000
    assert cli_main(["recover", str(cut), "--in-place"]) == 0
    assert "messages kept" in capsys.readouterr().out
    rec2 = Recording(cut)
    assert not rec2.truncated and not rec2.from_cache and len(rec2.topic("/follower/joint_state")) == n


def test_corrupt_chunk_is_skipped_with_a_warning(tmp_path):
    path = tmp_path / "s.mcap"
    record_session(path, n=2000, cameras=False, chunk_size=16 * 1024, compression="").close()
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 64] = os.urandom(64)
    path.write_bytes(bytes(data))
    with pytest.warns(UserWarning, match="corrupt chunk"):
        rec = Recording(path, use_cache=False)
    assert 500 < len(rec.topic("/follower/joint_state")) < 2000


@pytest.mark.parametrize("content, message", [
    (b"", "empty file"),
    (b"hello, not a recording at all", "not an MCAP file"),
    (b"\x89MCA", "too short"),
])
def test_bad_files_give_one_line_and_exit_2(tmp_path, capsys, content, message):
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=message):
        Recording(path)
    for argv in (["episodes", "show", str(path)], ["recover", str(path)]):
        assert cli_main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_foreign_mcap_is_rejected(tmp_path, capsys):
    from mcap.writer import Writer

    path = tmp_path / "ros.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="someone else")
        sid = w.register_schema("std_msgs/String", "ros2msg", b"string data")
        cid = w.register_channel("/chatter", "cdr", sid)
        w.add_message(cid, 1, b"\x00\x01", 1)
        w.finish()
    with pytest.raises(RecordingError, match="not a factr2 recording"):
        Recording(path)
    assert cli_main(["episodes", "show", str(path)]) == 2
    assert "not a factr2 recording" in capsys.readouterr().err


def test_disk_full_stops_cleanly_and_keeps_what_was_written(tmp_path):
    """A file-size limit on the writer process fails its writes as a full disk does (EFBIG for ENOSPC)."""
    from recording_helpers import joint_state

    path = tmp_path / "full.mcap"
    rec = Recorder(path, t0=0.0, flush_interval_s=0.02, compression="", chunk_size=16 * 1024,
                   max_file_bytes=200_000)  # small chunks: ~180 kB reach the "disk" first
    accepted = []
    for k in range(20000):
        accepted.append(rec.log_joint_state("follower", k * 1e-3, joint_state(k)))  # never raises
        if k % 200 == 0:
            time.sleep(0.01)
    st = rec.close()
    assert st.error and "too large" in st.error and "factr2 recover" in st.error
    assert not st.recording and not accepted[-1]
    with pytest.warns(UserWarning, match="truncated"):
        got = Recording(path, use_cache=False).topic("/follower/joint_state")
    assert len(got) > 100
    np.testing.assert_allclose(got.fields["q"][50], joint_state(50).q, rtol=1e-8)


def test_recorder_refuses_to_overwrite_and_bad_folders(tmp_path):
    from hardware.errors import UserError

    path = tmp_path / "a.mcap"
    path.write_bytes(b"x")
    with pytest.raises(UserError, match="already exists"):
        Recorder(path)
    with pytest.raises(UserError, match="cannot create recording"):
        Recorder("/proc/no/such/dir/x.mcap")


def test_malformed_samples_are_counted_not_raised(tmp_path):
    from recording_helpers import joint_state

    rec = Recorder(tmp_path / "m.mcap", t0=0.0)
    assert rec.log_joint_state("follower", 0.0, None) is False  # not a JointState
    assert rec.log_external_torque("follower", 0.0, None, True) is False
    assert rec.log_image("cam", 0.0, np.zeros((4, 4, 7), np.uint8)) is True  # rejected by the encoder thread
    assert rec.log_joint_state("follower", 0.001, joint_state(1)) is True
    st = rec.close()
    assert st.error is None and st.warning and st.dropped_samples == 2 and st.dropped_frames == 1
    assert len(Recording(tmp_path / "m.mcap").topic("/follower/joint_state")) == 1


def test_recovered_copy_is_listed_in_place_of_the_damaged_file(tmp_path, capsys):
    """`factr2 recover FILE` writes FILE.recovered.mcap beside FILE: every folder reader (episodes list,
    train, export, the app) then uses the copy alone, not both (each episode listed once)."""
    from hardware.recording.episodes import list_episodes
    from policies.data.recordings import recording_files

    path = tmp_path / "s.mcap"
    record_session(path, n=3000, episodes=2, flush_interval_s=0.05, chunk_size=32 * 1024).close()
    data = path.read_bytes()
    path.unlink()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 3 // 4])
    assert cli_main(["recover", str(cut)]) == 0
    assert "cut.recovered.mcap in its place" in capsys.readouterr().out
    assert recording_files([tmp_path]) == [tmp_path / "cut.recovered.mcap"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows = list_episodes(tmp_path)
    assert {r.file.name for r in rows} == {"cut.recovered.mcap"}
    assert len({r.index for r in rows}) == len(rows) >= 1
    assert recording_files([cut]) == [cut]  # named explicitly, a file is still read
