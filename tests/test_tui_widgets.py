"""Pure text building blocks of the TUI: bars, sparklines, progress, durations, text plots, episode table."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from factr2_teleop.tui.episodes import episode_table
from factr2_teleop.tui.widgets import bar, duration, eta, fmt, progress_bar, sparkline, text_plot
from hardware.recording.episodes import EpisodeRow


def test_bar_marks_zero_value_and_overflow():
    assert bar(0.0, -1, 1, 11) == "[----|----]"
    assert bar(1.0, -1, 1, 11) == "[----|####]"
    assert bar(-0.5, -1, 1, 11) == "[--##|----]"
    assert bar(5.0, -1, 1, 11).endswith(">]") and bar(-5.0, -1, 1, 11).startswith("[<")
    assert bar(float("nan"), -1, 1, 11) == "[?????????]"
    assert len({len(bar(v, -1, 1, 11)) for v in (-9, -1, 0, 0.3, 1, 9, np.nan)}) == 1


def test_sparkline_progress_and_numbers():
    s = sparkline([0, 1, 2, 3], 6)
    assert len(s) == 6 and s[-1] == "█" and s[2] == "▁"
    assert sparkline([], 4) == "    " and sparkline([np.nan], 3) == "?  "
    assert sparkline([1, 1, 1], 3) == "▁▁▁"  # flat: no division by zero
    assert progress_bar(0.5, 10) == "[#####.....]  50%" and progress_bar(np.nan, 4) == "[....]   0%"
    assert fmt(np.nan) == "     -" and fmt(1.234) == " +1.23"
    assert duration(75.25) == "01:15.2" and duration(np.nan) == "--:--.-"
    assert eta(125) == "ETA 2m05s" and eta(np.nan) == "ETA --"


def test_text_plot_has_marks_axes_and_labels():
    t = np.linspace(0, 2, 50)
    y = np.stack([np.sin(t), np.cos(t)], axis=1)
    txt = text_plot(t, y, width=40, height=6, title="q", unit="rad")
    lines = txt.splitlines()
    assert lines[0] == "q" and "1" in txt and "2" in txt and "t 0.0 s" in txt and "[rad]" in txt
    assert len(lines) == 1 + 6 + 2 and all(len(x) <= 80 for x in lines)
    assert text_plot([0.0], [[1.0]]) == "(no data)"


def test_episode_table_selection_and_summary():
    rows = [
        EpisodeRow(Path("/x/sim-piper-1.mcap"), i, o, "wipe", 0.0, 1.5, 100, 0.25)
        for i, o in enumerate(["success", "failure", "discard"])
    ]
    rows.append(EpisodeRow(Path("/x/bad.mcap"), -1, "unreadable", error="not an MCAP file"))
    lines = episode_table(rows, 1)
    assert lines[2].startswith(">  1") and "failure" in lines[2] and "25%" in lines[2]
    assert "not an MCAP file" in lines[4]
    assert lines[-1].startswith("  4 episode(s), 4.5 s total, 1 success, 1 failure")
    assert episode_table([], 0)[-1].startswith("  (no episodes yet")
