"""Text building blocks for the TUI: bars, sparklines, progress bars and a small text plot.

Pure functions returning plain strings (testable, readable in any terminal, light or dark, over SSH):
meaning never rests on colour alone -- every state is also a word or a symbol.
"""

from __future__ import annotations

import math

import numpy as np

SPARK = " ▁▂▃▄▅▆▇█"
PLOT_MARKS = "123456789abcdef"
SHADES = " .:"  # text_plot background per FIRST phase: free, pre-contact, contact


def fmt(x: float, width: int = 6, prec: int = 2) -> str:
    """A number right-aligned in `width`, '-' for NaN/None."""
    if x is None or not np.isfinite(x):
        return "-".rjust(width)
    return f"{x:+{width}.{prec}f}"


def bar(value: float, lo: float, hi: float, width: int = 10) -> str:
    """[----|##  ] a signed bar: '|' marks zero (when inside the range), '#' fills from zero to value,
    '<' / '>' at an end when the value is beyond the range, '?' everywhere when the value is not finite."""
    inner = max(width - 2, 3)
    if value is None or not np.isfinite(value) or not hi > lo:
        return "[" + "?" * inner + "]"

    def pos(v: float) -> int:
        return int(round((min(max(v, lo), hi) - lo) / (hi - lo) * (inner - 1)))

    z = pos(0.0) if lo <= 0.0 <= hi else (0 if value >= 0 else inner - 1)
    p = pos(value)
    cells = ["-"] * inner
    a, b = sorted((z, p))
    for i in range(a, b + 1):
        cells[i] = "#"
    if lo <= 0.0 <= hi:
        cells[z] = "|"
    if value > hi:
        cells[-1] = ">"
    elif value < lo:
        cells[0] = "<"
    return "[" + "".join(cells) + "]"


def progress_bar(frac: float, width: int = 30) -> str:
    """[#######.......]  42%"""
    f = 0.0 if frac is None or not np.isfinite(frac) else float(min(max(frac, 0.0), 1.0))
    n = int(round(f * width))
    return "[" + "#" * n + "." * (width - n) + f"] {100 * f:3.0f}%"


def sparkline(values, width: int = 30, lo: float | None = None, hi: float | None = None) -> str:
    """The last `width` values as block characters scaled between lo and hi (default: their min/max)."""
    v = np.asarray(list(values), dtype=float)[-width:]
    if v.size == 0:
        return " " * width
    finite = v[np.isfinite(v)]
    if finite.size == 0:
        return "?" * v.size + " " * (width - v.size)
    lo = float(np.min(finite)) if lo is None else lo
    hi = float(np.max(finite)) if hi is None else hi
    span = hi - lo if hi > lo else 1.0
    out = []
    for x in v:
        if not np.isfinite(x):
            out.append("?")
        else:
            out.append(SPARK[1 + int(round((min(max(x, lo), hi) - lo) / span * (len(SPARK) - 2)))])
    return "".join(out).rjust(width)


def duration(s: float) -> str:
    """mm:ss.s, '-' for NaN."""
    if s is None or not np.isfinite(s):
        return "--:--.-"
    m, sec = divmod(max(s, 0.0), 60.0)
    return f"{int(m):02d}:{sec:04.1f}"


def eta(s: float) -> str:
    if s is None or not np.isfinite(s):
        return "ETA --"
    return f"ETA {int(s // 60)}m{int(s % 60):02d}s" if s >= 60 else f"ETA {s:.0f}s"


def text_plot(
    t: np.ndarray,
    y: np.ndarray,
    width: int = 60,
    height: int = 8,
    title: str = "",
    unit: str = "",
    shade: np.ndarray | None = None,
) -> str:
    """A scatter plot of the columns of y (N, n) against t (N,) with one mark per column ('1', '2', ...),
    a y-axis with min/max labels and a t-axis line. Overlaps show the higher column's mark.
    shade (N,) ints: a level per sample; each plot column's background is SHADES[highest level in it]
    (FIRST phases: ' ' free, '.' pre-contact, ':' contact)."""
    t = np.asarray(t, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        y = y[:, None]
    lines = [title] if title else []
    ok = np.isfinite(y)
    if t.size < 2 or not ok.any():
        return "\n".join(lines + ["(no data)"])
    lo, hi = float(np.min(y[ok])), float(np.max(y[ok]))
    if math.isclose(lo, hi):
        lo, hi = lo - 1.0, hi + 1.0
    t0, t1 = float(t[0]), float(t[-1])
    cols = np.clip(((t - t0) / max(t1 - t0, 1e-12) * (width - 1)).round().astype(int), 0, width - 1)
    background = [" "] * width
    if shade is not None:
        level = np.zeros(width, dtype=int)
        np.maximum.at(level, cols, np.clip(np.asarray(shade, dtype=int).reshape(-1), 0, len(SHADES) - 1))
        background = [SHADES[v] for v in level]
    grid = [list(background) for _ in range(height)]
    for j in range(y.shape[1]):
        rows = ((hi - y[:, j]) / (hi - lo) * (height - 1)).round()
        for c, r in zip(cols, rows):
            if np.isfinite(r):
                grid[int(r)][c] = PLOT_MARKS[j % len(PLOT_MARKS)]
    lab_hi, lab_lo = f"{hi:+.2f}", f"{lo:+.2f}"
    w = max(len(lab_hi), len(lab_lo))
    for i, row in enumerate(grid):
        label = lab_hi if i == 0 else lab_lo if i == height - 1 else ""
        lines.append(f"{label:>{w}} |" + "".join(row))
    lines.append(" " * w + " +" + "-" * width)
    lines.append(
        " " * w
        + f"  t {t0:.1f} s"
        + f"{t1:.1f} s".rjust(width - 8 - len(f"{t0:.1f}"))
        + (f"  [{unit}]" if unit else "")
    )
    return "\n".join(lines)
