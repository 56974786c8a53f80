"""Published results without the machine's folders: every absolute path made portable (#53's review).

A result in results/ is read on other machines; a path like /work/fb/hl4/peg1 means nothing there and names
the machine it ran on. The writers (bench/first_ledger.py, bench/first_report.py, bench/first_force.py)
pass what they publish through portable() with the folders they know by name (OUT: the run's output
folder, BENCH_OUT, OUT_STATE); a path inside the repository becomes relative to it; any other absolute path
keeps its names below the top folder, under SCRATCH (/work/fb/e1/run -> SCRATCH/fb/e1/run). System paths
(/dev, /sys, /proc, /usr, /etc) are kept: they name a device or a system file, the same on every machine.

    python -m bench.portable --fix results/first_cells_perceived.json    # rewrite a result in place
    python -m bench.portable --check results/*.json docs/tui_captures/*.txt   # exit 1 if a path is left
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path, PurePosixPath

REPO = Path(__file__).resolve().parents[1]
SYSTEM = ("dev", "sys", "proc", "usr", "etc")  # top folders kept as they are
# an absolute path: a '/' at a line's start or after a space, '=', '+', ':', '(', '[', ',' or a quote, then
# names ('+' inside a name, as in a cell PC+C; after one, it joins paths: --demos-from t=/a/b+/c/d)
_NAME = r"[\w.\-]+(?:\+[\w.\-]+)*"
PATH = re.compile(rf"(?:^|(?<=[\s=+:(\[,'\"]))/{_NAME}(?:/(?:{_NAME})?)*", re.M)


def portable_path(path: str, roots: dict[str, str | Path] | None = None, repo: Path = REPO) -> str:
    """One absolute path made portable: NAME/rest under a named root (NAME -> folder, the longest match
    first), relative to `repo` inside it, SCRATCH/rest-below-the-top-folder otherwise; a relative path or a
    system path as given."""
    p = PurePosixPath(path)
    if not p.is_absolute() or (len(p.parts) > 1 and p.parts[1] in SYSTEM):
        return path
    named = [(n, PurePosixPath(f)) for n, f in (roots or {}).items() if f]
    for name, root in [*sorted(named, key=lambda x: -len(x[1].parts)), ("", PurePosixPath(repo))]:
        if p == root or root in p.parents:
            rest = p.relative_to(root).as_posix()
            if not name:
                return rest
            return name if rest == "." else f"{name}/{rest}"
    return "/".join(("SCRATCH", *p.parts[2:])) if len(p.parts) > 2 else "SCRATCH"


def portable_text(text: str, roots: dict[str, str | Path] | None = None, repo: Path = REPO) -> str:
    """Every absolute path in a text (a command line, a note) made portable by portable_path()."""
    return PATH.sub(lambda m: portable_path(m.group(0), roots, repo), text)


def portable(obj, roots: dict[str, str | Path] | None = None, repo: Path = REPO):
    """A JSON-like value (dicts, lists, strings, numbers) with every string made portable (a new value)."""
    if isinstance(obj, str):
        return portable_text(obj, roots, repo)
    if isinstance(obj, dict):
        return {k: portable(v, roots, repo) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [portable(v, roots, repo) for v in obj]
    return obj


def machine_paths(text: str) -> list[str]:
    """The absolute paths left in a text that portable_text() would change (none in a portable file)."""
    return [m.group(0) for m in PATH.finditer(text) if portable_path(m.group(0)) != m.group(0)]


def ledger_cell(cell: dict) -> dict:
    """A FIRST ledger cell (bench/first_ledger.py) made portable: its run folder OUT/TASK/CELL/seedN is named
    from its run's OUT (the folder three levels above it)."""
    run = (cell.get("train") or {}).get("run")
    roots = {"OUT": str(PurePosixPath(run).parents[2])} if run and PurePosixPath(run).is_absolute() else {}
    return portable(cell, roots)


def _roots_of(data, found: dict | None = None) -> dict:
    """The named folders a result records about itself: its `out` (OUT), `bench_out` (BENCH_OUT)."""
    found = {} if found is None else found
    if isinstance(data, dict):
        for key, name in (("out", "OUT"), ("bench_out", "BENCH_OUT")):
            if isinstance(data.get(key), str) and data[key].startswith("/"):
                found.setdefault(name, data[key])
        for v in data.values():
            _roots_of(v, found)
    elif isinstance(data, list):
        for v in data:
            _roots_of(v, found)
    return found


def fix(data):
    """A result file's content made portable: a ledger cell by cell, any other result with its own folders."""
    if isinstance(data, dict) and isinstance(data.get("cells"), list) and "version" in data:
        return {k: [ledger_cell(c) for c in v] if k == "cells" else portable(v) for k, v in data.items()}
    return portable(data, _roots_of(data))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fix", nargs="*", default=[], metavar="JSON", help="rewrite these results in place")
    ap.add_argument("--check", nargs="*", default=[], metavar="FILE",
                    help="list the machine paths in these files; exit 1 if any")
    a = ap.parse_args(argv)
    for f in a.fix:
        path = Path(f)
        text = path.read_text()
        tmp = path.with_name(f".{path.name}.tmp")  # as the writers write it: indent 1, its final newline kept
        tmp.write_text(json.dumps(fix(json.loads(text)), indent=1) + ("\n" if text.endswith("\n") else ""))
        tmp.replace(path)
        print(f"{path}: {len(machine_paths(path.read_text()))} machine path(s) left")
    left = {f: machine_paths(Path(f).read_text()) for f in a.check}
    for f, paths in left.items():
        for p in sorted(set(paths)):
            print(f"{f}: {p}")
    return 1 if any(left.values()) else 0


if __name__ == "__main__":
    raise SystemExit(main())
