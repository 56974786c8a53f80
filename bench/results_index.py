"""Write results/README.md, the index of the published results, from the files themselves.

    python -m bench.results_index           # (re)write results/README.md
    python -m bench.results_index --check   # exit 1 when results/README.md is not what the files say (CI)

Every results/*.json is a bench/harness.py record (experiment, command, commit, date, machine, simulated,
payload), except the FIRST benchmark's ledgers (results/first_cells*.json, bench/first_ledger.py: finished
cells with their own settings and environment). A file that is neither fails the index.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bench import harness

INDEX = harness.RESULTS / "README.md"
HEAD = """# Results

The published results of the benchmarks, one JSON file per experiment, named by experiment. Each is a
record of `bench/harness.py`: `experiment`, `command` (what reproduces it), `commit`, `date` (UTC),
`machine` (CPU model, cores, load, Python / torch / MuJoCo / numpy versions), `simulated`, and the numbers
under `payload`. A run writes to `bench/out/` (scratch); a result is published by copying it here and
citing it from a page of docs/. Tables in docs/ that come from these files are written by
`python -m bench.docs_tables` and checked by `tests/test_docs_tables.py`.

Files recorded before the harness existed carry the commit that published them (`commit_note`), the
machine as the run described it (the shared 2-vCPU dev VM, `lscpu`: AMD EPYC, unless said), and where the
command has changed form, `command_as_run` beside `command` (today's form, SCRATCH for a scratch folder).

This index is written by `python -m bench.results_index` (CI checks it is current).

"""
TAIL = ""


def _cell(x) -> str:
    return "" if x is None else str(x).replace("|", "\\|").replace("\n", " ")


def _machine(m) -> str:
    if not isinstance(m, dict):
        return _cell(m)
    if m.get("cpu"):
        return f"{m['cpu']}, {m.get('cores')} cores"
    if m.get("note"):
        return _cell(m["note"])[:60]
    bits = [str(m[k]) for k in ("platform", "cpus", "cores") if m.get(k)]
    return _cell(", ".join(bits))[:60]


def rows(results: Path = harness.RESULTS) -> tuple[list[str], list[str]]:
    """(record rows, ledger rows) of the index table."""
    recs, ledgers = [], []
    for p in sorted(results.glob("*.json")):
        data = json.loads(p.read_text())
        if p.stem.startswith("first_cells") and isinstance(data, dict) and "cells" in data:
            s = data.get("settings") or {}
            ledgers.append(f"| [{p.name}]({p.name}) | {len(data['cells'])} | obs {s.get('obs')}, precision "
                           f"{s.get('precision')}, labels: {_cell(s.get('labels'))}, limit tolerance "
                           f"{s.get('limit_tol_fraction')}, sampler {s.get('sampler_seeding')} |")
            continue
        if not harness.is_record(data):
            raise SystemExit(f"{p}: neither a result record (bench/harness.py) nor a FIRST ledger")
        sim = "SIMULATED" if data.get("simulated") else "hardware data"
        cmd = _cell(data.get("command"))
        recs.append(f"| [{p.name}]({p.name}) | {sim} | `{cmd}` | {data.get('commit') or ''} | "
                    f"{(data.get('date') or '')[:10]} | {_machine(data.get('machine'))} |" if cmd else
                    f"| [{p.name}]({p.name}) | {sim} | (see the citing page) | {data.get('commit') or ''} | "
                    f"{(data.get('date') or '')[:10]} | {_machine(data.get('machine'))} |")
    return recs, ledgers


def render(results: Path = harness.RESULTS) -> str:
    recs, ledgers = rows(results)
    return (HEAD + "| file | data | command | commit | date | machine |\n|---|---|---|---|---|---|\n"
            + "\n".join(recs) + "\n\n## FIRST ledgers (bench/first_ledger.py)\n\nFinished cells of "
            "`python -m bench.bench_first --ledger FILE`, kept across runs; a run imports the cells whose "
            "settings and demonstrations match its own.\n\n| file | cells | settings |\n|---|---|---|\n"
            + "\n".join(ledgers) + "\n" + TAIL)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only check that results/README.md is current")
    a = ap.parse_args(argv)
    return harness.write_or_check(INDEX, render(), a.check, "python -m bench.results_index")


if __name__ == "__main__":
    sys.exit(main())
