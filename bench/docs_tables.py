"""The tables of docs/ that come from results/: written from the results files, and checked against them.

    python -m bench.docs_tables           # rewrite every generated table in docs/ from results/
    python -m bench.docs_tables --check   # exit 1 when a table differs from its results file (CI:
                                          # tests/test_docs_tables.py)

A generated table sits between `<!-- table NAME: ... -->` and `<!-- /table NAME -->` in its page. The FIRST
benchmark's block in docs/first.md is written by `python -m bench.bench_first --write-docs` from a run's
folder (it needs the run's training losses and labels); here its success and progress numbers are checked
against results/first_headline.json, the raw per-rollout results written with it.
"""

from __future__ import annotations

import argparse
import re
import sys

import numpy as np

from bench import docs_tables_pages, harness
from bench.first_report import DOCS_BEGIN, DOCS_END, mcnemar_p, wilson

DOCS = harness.ROOT / "docs"


def _payload(name: str):
    return harness.payload(harness.load(harness.RESULTS / f"{name}.json"))


def _f(x, fmt: str = ".0f") -> str:
    return "-" if x is None else format(x, fmt)


# -- docs/faults.md: the fault campaign -------------------------------------------------------------------
FAULT_HEAD = ("| kind | injected (teleop/collect/rollout) | trials safe | safe_ms p50 / p99 / max | "
              "stale_ms p99 / max | violations | samples lost | recoveries | errors | run |\n"
              "|---|---|---|---|---|---|---|---|---|---|")
KILLED = "faults_crash.md"  # the page with the motors' side of a crash


def _fault_row(kind: str, r: dict, run: str, safe: str) -> str:
    acts = r.get("activities") or {}
    per = "/".join(str(acts[a]["injected"]) if a in acts else "-" for a in ("teleop", "collect", "rollout"))
    s, st = r["safe_ms"], r.get("stale_ms") or {}  # stale_ms: not recorded by the earliest runs
    return (f"| {kind} | {r['injected']} ({per}) | {safe} | {_f(s['p50'])} / {_f(s['p99'])} / "
            f"{_f(s['max'])} | {_f(st.get('p99'))} / {_f(st.get('max'))} | {r['violations']} | "
            f"{_f(r['samples_lost'], 'd')} | "
            f"{r['recoveries']}/{r['recovery_owed']} | {r['errors']} | {run} |")


def faults_campaign() -> str:
    camp, crash = _payload("faults_campaign"), _payload("faults_crash")
    by_kind = camp["sources"]["by_kind"]
    rows = [FAULT_HEAD]
    for kind, r in camp["kinds"].items():
        safe = f"{r['trials_safe']}/{r['trials']}"
        if r.get("safe_unobservable"):  # SIGKILL in-process: the twin dies with the app; the motors' side
            c = crash["kinds"][kind]  # is measured beside a twin in its own process
            safe = (f"recordings {r['recordings_open']}/{r['trials']} open; the motors: "
                    f"{c['trials_safe']}/{c['trials']} safe, {KILLED}")
        rows.append(_fault_row(kind, r, by_kind[kind], safe))
        for extra, c in crash["kinds"].items():
            if extra not in camp["kinds"] and kind == "app_sigkill":
                rows.append(_fault_row(extra, c, "crash", f"{c['trials_safe']}/{c['trials']}, {KILLED}"))
    return "\n".join(rows)


# -- docs/diagnosis_payload.md: a payload on the real UR5, springs on the twin ----------------------------
UR5_CASES = {"known": "scale known (`torque constants`: the controller's ratio)",
             "referenced": "referenced (`description masses`: the prior's scales)",
             "known mass": "known mass (`known mass`: {ref} kg on the reference runs)",
             "unknown": "unknown (`none`)"}


def payload_ur5_cases() -> str:
    d = _payload("diagnosis_payload_ur5")
    rows = ["| case (reference) | first found | mass found [kg] (95 %) | centre of mass found [cm] "
            "(95 % per axis) | centre error [cm] |", "|---|---|---|---|---|"]
    for case, label in UR5_CASES.items():
        c = d["cases"][case]
        p = c["payload"]
        lo, hi = p["interval"]["mass"]
        if p.get("mass_kg") is None:
            mass = f"cannot be stated in kg ({p['mass']:.3f} x an unknown factor; {lo:.2f}-{hi:.2f})"
        else:
            mass = f"**{p['mass_kg']:.3f}** ({100 * c['mass_err']:+.1f} %; {lo:.2f}-{hi:.2f})"
        com = ", ".join(f"{100 * x:.1f}" for x in p["com_m"])
        ci = " / ".join(f"{100 * a:.1f}..{100 * b:.1f}" for a, b in p["interval"]["com_m"])
        rows.append(f"| {label.format(ref=d['reference_runs']['mass_kg'])} | {c['first']} | {mass} | "
                    f"{com} ({ci}) | {100 * c['com_err_m']:.1f} |")
    return "\n".join(rows)


def _joint_row(label: str, xs, mean: bool) -> str:
    cells = [f"{x:.3f}" for x in xs] + ([f"{np.mean(xs):.3f}"] if mean else [])
    return f"| {label} | " + " | ".join(cells) + " |"


def payload_ur5_l1() -> str:
    d = _payload("diagnosis_payload_ur5")
    c = d["cases"]
    return "\n".join([
        "| held-out L1 [A] | " + " | ".join(d["joints"]) + " | mean |", "|---" * (len(d["joints"]) + 2) + "|",
        _joint_row("prior without payload, on the runs without it (floor)", d["heldout_l1_unloaded_floor"],
                   True),
        _joint_row("prior on the loaded runs (before)", c["known"]["heldout_l1_before"], True),
        _joint_row("after, known", c["known"]["heldout_l1_after"], True),
        _joint_row("after, referenced", c["referenced"]["heldout_l1_after"], True)])


def payload_ur5_current() -> str:
    d = _payload("diagnosis_payload_ur5")
    c = d["cases"]
    return "\n".join([
        "| payload current, RMS over the held-out runs [A] | " + " | ".join(d["joints"]) + " |",
        "|---" * (len(d["joints"]) + 1) + "|",
        _joint_row("injected", c["known"]["payload_current_rms_true_A"], False),
        *[_joint_row(f"found, {k}", c[k]["payload_current_rms_found_A"], False)
          for k in ("known", "referenced", "unknown")]])


SHORT = {"position_spring": "spring", "current_offset": "offset"}


def _spring_found(r: dict | None) -> str:
    if r is None or r.get("first") is None:
        return "not found (the free rigid part absorbs it)"
    name, j = r["first"]
    first = "spring" if name == "position_spring" else f"{SHORT.get(name, name)} j{j} first, spring second"
    return f"{first}, {r['k_found']:.3f} ({_pct(r['k_found_err'])})"


def _pct(err: float) -> str:
    s = f"{100 * err:+.1f} %" if abs(err) >= 0.001 else f"{100 * err:+.2f} %"
    return f"**{s}**" if abs(err) > 0.10 else s


def springs_twin() -> str:
    rows = _payload("diagnosis_springs_twin")["rows"]
    out = ["| joint | k true [N*m/rad] | gravity R^2 | held to the description (1.0): first, k found | "
           "its refit, rigid part free | rigid part free from the start (1e-3): first, k found |",
           "|---|---|---|---|---|---|"]
    held = [r for r in rows if r["prior_weight"] == 1.0]
    for r in held:
        free = next((x for x in rows if x["prior_weight"] != 1.0 and x["joint"] == r["joint"]
                     and x["k_true"] == r["k_true"] and x["q0"] == r["q0"]), None)
        r2 = f"{r['gravity_r2']:.3f}" if r["gravity_r2"] >= 0.99 else f"{r['gravity_r2']:.2f}"
        out.append(f"| {r['joint']} | {r['k_true']:+.1f} (rest {r['q0']:.1f}) | {r2} | {_spring_found(r)} | "
                   f"{r['k_free_rigid']:.3f} ({_pct(r['k_free_rigid_err'])}) | {_spring_found(free)} |")
    return "\n".join(out)


# -- docs/first.md: the headline in one table per results file ---------------------------------------------
def _pooled(seeds: list[dict]) -> tuple[int, int]:
    return sum(sum(x["success"]) for x in seeds), sum(len(x["success"]) for x in seeds)


def _p(p: float) -> str:
    """A p-value as the pages write it: 0.50, 0.071, 0.003."""
    return f"{p:.2f}" if p >= 0.1 else f"{p:.2g}" if p >= 0.01 else f"{p:.1g}"


def _stages(seeds: list[dict]) -> dict[str, float]:
    """Share of all episodes that reached each stage (the seeds' stage_rates, weighted by episodes)."""
    n = sum(len(x["success"]) for x in seeds)
    out: dict[str, float] = {}
    for x in seeds:
        for k, v in (x.get("stage_rates") or {}).items():
            out[k] = out.get(k, 0.0) + v * len(x["success"]) / n
    return out


def _rate_cell(k: int, n: int, best: float) -> str:
    """A pooled success rate with its 95 % Wilson interval, bold when it is the task's best."""
    lo, hi = wilson(k, n)
    pct = f"{100 * k / n:.0f} %"
    return f"{f'**{pct}**' if k / n == best else pct} [{100 * lo:.0f}, {100 * hi:.0f}]"


def headline(name: str, stage_column: bool) -> str:
    """first against base-torque per task: pooled success [95 % Wilson], per seed, the paired episodes."""
    raw = _payload(name)
    head = ("| task | base-torque [95 % Wilson] | first | per seed bt / first [%] | paired: only first / "
            "only bt, McNemar p |")
    rows = [head + (" stage that fails |" if stage_column else ""), "|---" * (6 if stage_column else 5) + "|"]
    for task in (t for t in raw if t != "config"):
        bt = sorted(raw[task]["base-torque"]["seeds"], key=lambda x: x["seed"])
        fi = sorted(raw[task]["first"]["seeds"], key=lambda x: x["seed"])
        rates = {m: _pooled(v) for m, v in (("bt", bt), ("first", fi))}
        best = max(k / n for k, n in rates.values())
        per = " / ".join(" ".join(f"{100 * np.mean(x['success']):.0f}" for x in v) for v in (bt, fi))
        only_f = sum(a > b for x, y in zip(fi, bt) for a, b in zip(x["success"], y["success"]))
        only_b = sum(b > a for x, y in zip(fi, bt) for a, b in zip(x["success"], y["success"]))
        row = (f"| {task} | {_rate_cell(*rates['bt'], best)} | {_rate_cell(*rates['first'], best)} | {per} | "
               f"{only_f} / {only_b}, "
               f"p = {_p(mcnemar_p(only_f, only_b))} |")
        if stage_column:
            sb, sf = _stages(bt), _stages(fi)
            names = list(sb)
            if min(k / n for k, n in rates.values()) >= 0.95 or len(names) < 2:  # no stage fails
                row += " -- |"
            else:
                lo, hi = sorted((100 * sb[names[-2]], 100 * sf[names[-2]]))
                row += f" {names[-1]} ({names[-2]} {lo:.0f}-{hi:.0f} %) |"
        rows.append(row)
    return "\n".join(rows)


ABLATION = (("base", "base (no force input)", "1:1:1"), ("C", "C", "1:1:5"), ("first", "PC = first", "1:5:1"),
            ("PC+C", "PC+C", "1:3:3"))


def ablation(name: str = "first_ablation", task: str = "peg-insert") -> str:
    """The re-sampling ratio on one task: each cell's pooled success, per seed, stages, paired with first."""
    raw = _payload(name)[task]
    cells = {m: sorted(raw[m]["seeds"], key=lambda x: x["seed"]) for m, _, _ in ABLATION}
    rates = {m: _pooled(v) for m, v in cells.items()}
    best = max(k / n for k, n in rates.values())
    rows = ["| method | w_F:w_PC:w_C | success [95 % Wilson] | per seed [%] | stages: "
            + " / ".join(_stages(cells["first"])) + " [%] | paired against first: only this / only first, "
            "McNemar p |", "|---|---|---|---|---|---|"]
    for m, label, ratio in ABLATION:
        per = " / ".join(f"{100 * np.mean(x['success']):.0f}" for x in cells[m])
        stages = " / ".join(f"{100 * v:.0f}" for v in _stages(cells[m]).values())
        if m == "first":
            paired = "--"
        else:
            pairs = [(a, b) for x, y in zip(cells[m], cells["first"])
                     for a, b in zip(x["success"], y["success"])]
            only_m, only_f = sum(a > b for a, b in pairs), sum(b > a for a, b in pairs)
            p = mcnemar_p(only_m, only_f)
            paired = f"{only_m} / {only_f}, " + (f"**p = {_p(p)}**" if p < 0.05 else f"p = {_p(p)}")
        rows.append(f"| {label} | {ratio} | {_rate_cell(*rates[m], best)} | {per} | {stages} | {paired} |")
    return "\n".join(rows)


# -- docs/force.md: what force buys a policy (issue #51) ----------------------------------------------------
def force_table(name: str) -> str:
    from bench.first_force import render

    return render(_payload(name))


def data_curve_table(name: str) -> str:
    from bench.data_curve_report import table

    return table(_payload(name)["summary"])


def history_table(name: str) -> str:
    from bench.force_history import table

    return table(_payload(name)["rows"])


# page, name -> (results files it reads, renderer)
TABLES = {
    ("faults.md", "faults_campaign"): (("faults_campaign", "faults_crash"), faults_campaign),
    ("first.md", "headline"): (("first_headline",), lambda: headline("first_headline", True)),
    ("first.md", "ablation"): (("first_ablation",), ablation),
    ("first_runs.md", "ablation_fp32_hysteresis"): (
        ("first_ablation_fp32_hysteresis",), lambda: ablation("first_ablation_fp32_hysteresis")),
    ("first_runs.md", "headline_fp32_hysteresis"): (
        ("first_headline_fp32_hysteresis",), lambda: headline("first_headline_fp32_hysteresis", False)),
    ("diagnosis_payload.md", "payload_ur5_cases"): (("diagnosis_payload_ur5",), payload_ur5_cases),
    ("diagnosis_payload.md", "payload_ur5_l1"): (("diagnosis_payload_ur5",), payload_ur5_l1),
    ("diagnosis_payload.md", "payload_ur5_current"): (("diagnosis_payload_ur5",), payload_ur5_current),
    ("diagnosis_payload.md", "springs_twin"): (("diagnosis_springs_twin",), springs_twin),
    ("force.md", "force_perceived"): (("force_perceived",), lambda: force_table("force_perceived")),
    ("force.md", "force_history"): (("force_history_perceived",),
                                    lambda: history_table("force_history_perceived")),
    ("data_curve.md", "data_curve"): (("data_curve_current",),
                                      lambda: data_curve_table("data_curve_current")),
    **docs_tables_pages.TABLES,
}


def _markers(name: str, files: tuple) -> tuple[str, str]:
    src = ", ".join(f"results/{f}.json" for f in files)
    return (f"<!-- table {name}: written by `python -m bench.docs_tables` from {src} -->",
            f"<!-- /table {name} -->")


def render_page(text: str, page: str) -> str:
    for (p, name), (files, fn) in TABLES.items():
        if p != page:
            continue
        begin, end = _markers(name, files)
        if begin not in text or end not in text:
            raise SystemExit(f"docs/{page}: the markers of table {name} are missing ({begin})")
        head, rest = text.split(begin, 1)
        _, tail = rest.split(end, 1)
        pad = head[len(head.rstrip(" ")):]  # a table inside a list item keeps the item's indent
        body = "\n".join(pad + line if line else line for line in fn().split("\n"))
        text = f"{head}{begin}\n{body}\n{pad}{end}{tail}"
    return text


# -- docs/first.md: the FIRST block against results/first_headline.json -----------------------------------
ROW = re.compile(r"^\| (?P<method>[\w+-]+) \| [\d:?]+ \| \*\*(?P<pooled>\d+) %\*\* "
                 r"\[(?P<lo>\d+), (?P<hi>\d+)\] \| (?P<per_seed>[\d /na]+) \| "
                 r"(?P<pm>[\d.]+) ± (?P<ps>[\d.]+) \|.* \| (?P<seeds>\d+) x (?P<n>\d+) \|$")


def first_block_problems(page: str | None = None, raw: dict | None = None) -> list[str]:
    """Every number of the FIRST block's success / progress columns that its results file does not give."""
    text = page if page is not None else (DOCS / "first.md").read_text()
    raw = raw if raw is not None else _payload("first_headline")
    block = text.split(DOCS_BEGIN, 1)[1].split(DOCS_END, 1)[0]
    problems, task, seen = [], None, 0
    for line in block.splitlines():
        m = re.match(r"^\*\*([\w-]+)\*\* \(demonstrations", line)
        if m:
            task = m.group(1)
            continue
        m = ROW.match(line)
        if not m or task is None:
            continue
        seen += 1
        seeds = raw.get(task, {}).get(m["method"], {}).get("seeds")
        if not seeds:
            problems.append(f"{task} {m['method']}: not in results/first_headline.json")
            continue
        succ = [s["success"] for s in sorted(seeds, key=lambda s: s["seed"])]
        k, n = sum(map(sum, succ)), sum(map(len, succ))
        lo, hi = wilson(k, n)
        prog = np.array([np.mean(s["progress"]) for s in sorted(seeds, key=lambda s: s["seed"])])
        want = {"pooled": f"{100 * k / n:.0f}", "lo": f"{100 * lo:.0f}", "hi": f"{100 * hi:.0f}",
                "per_seed": " / ".join(f"{100 * np.mean(x):.0f}" for x in succ),
                "pm": f"{prog.mean():.2f}", "ps": f"{prog.std(ddof=1) if len(prog) > 1 else 0.0:.2f}",
                "seeds": str(len(succ)), "n": str(max(map(len, succ)))}
        for key, v in want.items():
            if m[key].strip() != v:
                problems.append(f"{task} {m['method']} {key}: docs/first.md says {m[key].strip()}, "
                                f"results/first_headline.json gives {v}")
    if not seen:
        problems.append("docs/first.md: no method row found in the FIRST block")
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only check; exit 1 on a difference")
    a = ap.parse_args(argv)
    stale = []
    for page in sorted({p for p, _ in TABLES}):
        path = DOCS / page
        text = path.read_text()
        new = render_page(text, page)
        if new != text:
            stale.append(f"docs/{page}")
            if not a.check:
                path.write_text(new)
    problems = first_block_problems()
    for p in problems:
        print(f"FIRST block: {p}", file=sys.stderr)
    if a.check:
        for p in stale:
            print(f"{p}: a generated table differs from its results file: run `python -m bench.docs_tables`",
                  file=sys.stderr)
        ok = not stale and not problems
        print("docs tables: current" if ok else "docs tables: STALE")
        return 0 if ok else 1
    print(f"rewrote {', '.join(stale) or 'nothing'}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
