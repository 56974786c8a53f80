"""More of docs/'s generated tables: the renderers bench/docs_tables.py imports (TABLES here is merged into
its own), kept apart so that each file stays short. Each renderer reads one committed results file and returns
the Markdown table its page holds between `<!-- table NAME: ... -->` and `<!-- /table NAME -->`.
"""

from __future__ import annotations

import numpy as np

from bench import docs_tables_curve, harness

HELD = ("Movement_No7_Acc_slow_Verify_Model_short", "TEST")  # the UR5's held-out pair (next_real_arms.md)


def _payload(name: str):
    return harness.payload(harness.load(harness.RESULTS / f"{name}.json"))


def _heldout_runs(runs: list[dict], variant: str) -> list[dict]:
    """A variant's held-out runs, by training seed."""
    held = [r for r in runs if r["variant"] == variant and r["fold"] == "heldout"]
    return sorted(held, key=lambda r: r["seed"])


def _range(xs, fmt: str = ".3f") -> str:
    lo, hi = min(xs), max(xs)
    return f"{lo:{fmt}}" if format(lo, fmt) == format(hi, fmt) else f"{lo:{fmt}}-{hi:{fmt}}"


# -- docs/next_real_arms.md: NEXT's variants on the UR5 (L1 in A) --------------------------------------------
UR5_VARIANTS = (  # (key in results/next_ur5_experiments.json, the page's label)
    ("q-qd-inputs (no q_cmd - q)", "inputs q, q_dot (no q_cmd - q)"),
    ("input noise 0.1 (augmentation)", "input noise 0.1 normalised units (augmentation)"),
    ("short (3 epochs)", "3 epochs only"),
    ("long (150 s budget, 20 epochs)", "150 s budget, 20 epochs"),
    ("hidden 128", "hidden 128"),
    ("robust normaliser", "robust normaliser (median / IQR)"),
    ("history 25", "history 25"),
    ("weight decay 1e-2", "weight decay 1e-2"),
    ("plain (--prior none)", "plain NEXT (no prior)"))


def _per_file(per_file: dict, method: str = "next") -> str:
    return " / ".join(f"{per_file[f][method]:.3f}" for f in HELD)


def ur5_variants() -> str:
    """Each variant of the default NEXT: CV over the six training runs, once on the held-out pair (seed 0)."""
    d = _payload("next_ur5_experiments")
    s, runs = d["summary"], d["runs"]
    best = min(s[k]["cv_next"] for k, _ in UR5_VARIANTS)
    seeds = [r for r in _heldout_runs(runs, "default") if r["seed"] != 0]
    others = ", ".join(f"{r['l1']['next']:.3f}" for r in seeds)
    default = s["default"]
    rows = ["| variant | CV NEXT | held-out NEXT (No7_short / TEST) |", "|---|---|---|",
            f"| the default without item 6's gate (block validation; seed 0; seeds "
            f"{', '.join(str(r['seed']) for r in seeds)}: held-out {others}) | {default['cv_next']:.3f} | "
            f"{default['heldout_next']:.3f} ({_per_file(default['heldout_per_file'])}) |",
            f"| ensemble of the default's {len(default['heldout_next_seeds'])} seeds (estimates averaged) | "
            f"{default['cv_ensemble']:.3f} | {default['heldout_ensemble']:.3f} |"]
    for key, label in UR5_VARIANTS:
        v = s[key]
        cv = f"{v['cv_next']:.3f}"
        rows.append(f"| {label} | {f'**{cv}**' if v['cv_next'] == best else cv} | {v['heldout_next']:.3f} "
                    f"({_per_file(v['heldout_per_file'])}) |")
    return "\n".join(rows)


def ur5_load_friction() -> str:
    """The identified-current prior with and without a load-dependent friction column, held out (L1 [A])."""
    res = _payload("next_ur5_load_friction")["results"]
    rows = ["| identified-current prior | prior alone | No7_short / TEST | NEXT on it |", "|---|---|---|---|"]
    for key, label in (("base", "as shipped"), ("load", "+ friction growing with the transmitted load")):
        h = res[key]["heldout"]
        rows.append(f"| {label} | {h['prior']:.3f} | {_per_file(h['per_file'], 'prior')} | {h['next']:.3f} |")
    return "\n".join(rows)


UR5_GATE = (  # (key in results/next_ur5_gate_experiments.json, the page's label, bold)
    ("blocks (before: block validation, no gate)", "block validation, no gate (`--variants blocks`)",
     False),
    ("runs-nogate (whole-run validation, no gate)",
     "(a) one whole run held out as validation (`runs-nogate`)", False),
    ("runs-gate (whole-run validation, gate fitted on that run)",
     "(a) + (b) gate fitted on that run (`runs-gate`)", False),
    ("default", "the default: gate cross-fitted over 3 groups of runs", True))


def ur5_gate() -> str:
    """The gate's variants, three training seeds each: CV and held out per seed, ranges, training time [s]."""
    d = _payload("next_ur5_gate_experiments")
    s, runs = d["summary"], d["runs"]
    prior = s["default"]
    rows = ["| variant | CV NEXT, seeds 0 / 1 / 2 (mean) | held-out NEXT, seeds 0, 1, 2 | "
            "No7_short / TEST, range | train s |", "|---|---|---|---|---|",
            f"| grey box alone | {prior['cv_prior']:.4f} | {prior['heldout_prior']:.4f} | "
            f"{_per_file(prior['heldout_per_file'], 'prior')} | fit |"]
    for key, label, bold in UR5_GATE:
        held = _heldout_runs(runs, key)
        cv = s[key]["cv_next_seeds"]
        b = (lambda x: f"**{x}**") if bold else (lambda x: x)
        ranges = " / ".join(_range([r["per_file"][f]["next"] for r in held]) for f in HELD)
        train = _range([r["train_seconds"] for r in runs if r["variant"] == key], ".0f")
        held_next = ", ".join(f"{r['l1']['next']:.3f}" for r in held)
        cv_seeds = " / ".join(f"{x:.3f}" for x in cv)
        rows.append(f"| {b(label)} | {cv_seeds} ({b(f'{np.mean(cv):.3f}')}) | {b(held_next)} | {ranges} | "
                    f"{train} |")
    return "\n".join(rows)


# -- docs/force.md: cap-screw's contact labels tried on development episodes ---------------------------------
LABEL_DEV = (("first", "first, labels `l1` (the benchmark's)"), ("first-motion", "first, labels `motion`"),
             ("base-torque", "base-torque (the benchmark's)"))


def label_dev() -> str:
    """Each policy's success [95 % Wilson], mean progress and stage shares on the development episodes."""
    d = _payload("first_label_dev_cap_screw")
    cells, cfg = d["cells"], d["config"]
    stages = list(cells["first"]["stages"])
    seeds = ", ".join(str(s) for s in cfg["seeds"])
    rows = [f"| policy (training seed {seeds}), development seed {cfg['rollout_seed']} | "
            f"success [95 % Wilson] | progress | {' / '.join(stages)} reached |", "|---|---|---|---|"]
    for key, label in LABEL_DEV:
        c = cells[key]
        lo, hi = c["wilson"]
        reached = " / ".join(f"{100 * c['stages'][s]:.0f}" for s in stages)
        rate = f"{c['k']} / {c['n']} = {100 * c['success']:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]"
        rows.append(f"| {label} | {rate} | {c['progress']:.2f} | {reached} % |")
    return "\n".join(rows)


# -- docs/takeover.md: the DAgger round with the carry-on operator (round 5) ---------------------------------
def _episodes_row(label: str, eps: list[dict]) -> str:
    """Success [95 % Wilson], the share of episodes that reached each stage [%], mean progress."""
    from bench.first_report import wilson

    k, n = sum(e["outcome"] == "success" for e in eps), len(eps)
    lo, hi = wilson(k, n)
    reached = " / ".join(f"{round(100 * np.mean([e['stages'][s] is not None for e in eps]), 1):g}"
                         for s in eps[0]["stages"])
    return (f"| {label} | {k} / {n} = {100 * k / n:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}] | {reached} % | "
            f"{np.mean([e['progress'] for e in eps]):.2f} |")


def dagger_round5() -> str:
    """run0 (shared by rounds 4 and 5: its evaluation is round 4's), run1 and run1b of round 5."""
    d = _payload("peg_dagger_rounds4_5")
    r5 = d["round5"]
    stages = " / ".join(d["round4"]["eval"]["run0"]["episodes"][0]["stages"])
    return "\n".join([
        f"| policy | success [95 % Wilson] | {stages} | progress |", "|---|---|---|---|",
        _episodes_row("run0 (45 demos)", d["round4"]["eval"]["run0"]["episodes"]),
        _episodes_row("run1 (DAgger, carry-on operator)", r5["eval"]["run1"]["episodes"]),
        _episodes_row(f"run1b (equal operator time, {r5['K']} demos)", r5["eval"]["run1b"]["episodes"])])


# -- docs/first_runs.md: FIRST on images (wipe, one training seed), each initial condition counted once ------
FIRST_BLOCK = 16  # the first episodes (one block per process): their seeds right and shared by both policies


def first_images() -> str:
    """Success over distinct initial conditions (each seed's first episode) [95 % Wilson], all episodes, the
    first FIRST_BLOCK, mean progress, and the validation loss per phase (F / PC / C) of each policy."""
    from bench.first_report import wilson

    d = _payload("first_images")
    val = {t["cell"]: t for t in d["train"]}
    rollouts = d["rollout"]
    n_all = len(rollouts[0]["episodes"])
    seeds = [e["seed"] for e in sorted(rollouts[0]["episodes"], key=lambda e: e["index"])[:FIRST_BLOCK]]
    rows = [f"| method | success, distinct initial conditions [95 % Wilson] | all {n_all} episodes | "
            f"first {FIRST_BLOCK} ({seeds[0]}-{seeds[-1]}) | progress ({n_all}) | val loss F / PC / C |",
            "|---|---|---|---|---|---|"]
    for r in rollouts:
        eps = sorted(r["episodes"], key=lambda e: e["index"])
        first: dict[int, dict] = {}
        for e in eps:
            first.setdefault(e["seed"], e)
        k, n = sum(e["outcome"] == "success" for e in first.values()), len(first)
        lo, hi = wilson(k, n)
        ok = [e["outcome"] == "success" for e in eps]
        cell = r["cell"]
        ratio = val[cell]["ratio"]
        label = cell if all(x == 1 for x in ratio) else f"{cell} ({':'.join(f'{x:g}' for x in ratio)})"
        loss = " / ".join(f"{val[cell]['val'][f'val/loss_{p}']:.3f}" for p in ("F", "PC", "C"))
        rows.append(f"| {label} | **{k} / {n} = {100 * k / n:.0f} %** [{100 * lo:.0f}, {100 * hi:.0f}] | "
                    f"{sum(ok)} / {len(ok)} | {sum(ok[:FIRST_BLOCK])} / {FIRST_BLOCK} | "
                    f"{np.mean([e['progress'] for e in eps]):.2f} | {loss} |")
    return "\n".join(rows)


# -- docs/faults_crash.md: the app killed or frozen beside a twin in its own process -------------------------
def _three(p: dict, fmt: str) -> str:
    return " / ".join(format(p[k], fmt) for k in ("p50", "p99", "max"))


def _crash_row(kind: str, activity: str, r: dict) -> str:
    """One row: an activity's trials, or (activity "all") the kind's, with its headline cells in bold."""
    b = (lambda x: f"**{x}**") if activity == "all" else (lambda x: x)
    recovered = f"{r['recoveries']}/{r['recovery_owed']}" if r["recovery_owed"] else "-"
    if r["recovery_owed"] and activity == "all":
        recovered = f"{b(recovered)}, {r['jumps']} jumps"
    after, before = r.get("follower_speed_after_resume_rad_s"), r.get("follower_speed_before_rad_s")
    speed = (f"{after['p50']:.2f} / {after['max']:.2f} ({before['p50']:.2f} / {before['max']:.2f})"
             if after else "-")
    safe = f"{r['trials_safe']}/{r['trials']}"
    tau = f"{r['leader_tau_after_nm_max']:.1f}"
    return (f"| {b(kind)} | {activity} | {b(r['injected'])} | {b(safe)} | "
            f"{b(_three(r['fallback_ms'], '.0f'))} | {_three(r['fallback_deadline_ms'], '.0f')} | "
            f"{b(tau)} | {_three(r['follower_motion_rad'], '.3f')} | "
            f"{recovered} | {speed} | {r['twin_overruns']} | {r['errors']} |")


def crash_kinds() -> str:
    kinds = _payload("faults_crash")["kinds"]
    rows = ["| kind | activity | injected | trials safe | fallback_ms p50 / p99 / max | "
            "from the motors' deadlines | leader torque after [N*m], max | "
            "follower motion [rad] p50 / p99 / max | recovered | "
            "follower peak speed [rad/s] after SIGCONT p50 / max (before the freeze) | twin overruns | "
            "errors |",
            "|---" * 12 + "|"]
    for kind, r in kinds.items():
        rows += [_crash_row(kind, a, r["activities"][a]) for a in ("teleop", "collect", "rollout")]
        rows.append(_crash_row(kind, "all", r))
    return "\n".join(rows)


def crash_rigs() -> str:
    """Per rig and kind, the max over its trials of each device's time to fallback [ms], the follower's
    motion [rad] p50 / max, and after a freeze the follower's peak speed [rad/s] after SIGCONT / before."""
    trials = _payload("faults_crash")["trials"]
    rows = ["| rig | kind | fallback_ms per device (max) | follower motion [rad] p50 / max | "
            "follower peak speed [rad/s] after SIGCONT / before the freeze (max) |", "|---|---|---|---|---|"]
    for kind in dict.fromkeys(x["kind"] for x in trials):
        for rig in dict.fromkeys(x["rig"] for x in trials):
            ts = [x for x in trials if x["kind"] == kind and x["rig"] == rig]
            devs: dict[str, float] = {}
            for x in ts:
                for dev, ms in x["fallback_ms_per_device"].items():
                    devs[dev] = max(devs.get(dev, 0.0), ms)
            order = sorted(devs, key=lambda d: ("follower" in d, d))  # leaders first
            fallback = ", ".join(f"{d} {devs[d]:.0f}" for d in order)
            motion = [x["follower_motion_rad"] for x in ts]
            speed = "-"
            if ts[0].get("follower_speed_after_resume_rad_s") is not None:
                speed = " / ".join(f"{max(x[k] for x in ts):.2f}" for k in
                                   ("follower_speed_after_resume_rad_s", "follower_speed_before_rad_s"))
            rows.append(f"| {rig} | {kind} | {fallback} | {np.percentile(motion, 50):.3f} / "
                        f"{max(motion):.3f} | {speed} |")
    return "\n".join(rows)


LABEL_SPLIT_COLUMNS = (("otsu", (2 / 3, 1.25)), ("min-error", (0.5, 0.8)), ("min-error", (0.5, 0.9)),
                       ("min-error", (0.5, 1.0)))


BAND_NAMES = {0.5: "1/2", 2 / 3: "2/3", 0.8: "4/5", 0.9: "9/10", 1.0: "1", 1.25: "5/4"}


def _band(b) -> str:
    return ":".join(BAND_NAMES.get(x, f"{x:.3g}") for x in b)


def label_split(name: str) -> str:
    """docs/first_labels.md: the recording thresholds' valley placed by Otsu's split and by the minimum-error
    one, with bands around it, against the twin's truth (bench/label_truth.py --split --band): per set,
    recall / FP and the labelled contact share of each candidate."""
    from pathlib import Path

    rows = _payload(name)["rows"]
    cols = [(sp, b) for sp, b in LABEL_SPLIT_COLUMNS
            if any(r["split"] == sp and np.allclose(r["band"], b) for r in rows)]
    out = ["| set (episodes) | true contact | " + " | ".join(f"{sp} {_band(b)}: recall / FP (contact)"
                                                           for sp, b in cols) + " |",
           "|---|---|" + "---|" * len(cols)]
    for d in dict.fromkeys(r["dir"] for r in rows):
        mine = [r for r in rows if r["dir"] == d]
        where = Path(d).name
        what = f"part {int(where[4:])}" if where.startswith("part") else \
            ("parts 0-2" if where == mine[0]["set"] else where.split("-")[-1])
        cells = []
        for sp, b in cols:
            r = next(r for r in mine if r["split"] == sp and np.allclose(r["band"], b))
            cells.append(f"{100 * r['recall']:.1f} / {100 * r['fp']:.1f} % ({100 * r['shares'][2]:.0f} %)")
        r0 = mine[0]
        head = f"| {r0['set']}, {what} ({r0['episodes']}) | {100 * r0['truth_contact']:.1f} % | "
        out.append(head + " | ".join(cells) + " |")
    return "\n".join(out)


# page, name -> (results files it reads, renderer); merged into bench.docs_tables.TABLES
TABLES = {
    ("faults_crash.md", "crash_kinds"): (("faults_crash",), crash_kinds),
    ("faults_crash.md", "crash_rigs"): (("faults_crash",), crash_rigs),
    ("first_runs.md", "first_images"): (("first_images",), first_images),
    ("takeover.md", "dagger_round5"): (("peg_dagger_rounds4_5",), dagger_round5),
    ("force.md", "label_dev_cap_screw"): (("first_label_dev_cap_screw",), label_dev),
    ("next_real_arms.md", "ur5_variants"): (("next_ur5_experiments",), ur5_variants),
    ("next_real_arms.md", "ur5_gate"): (("next_ur5_gate_experiments",), ur5_gate),
    ("next_real_arms.md", "ur5_load_friction"): (("next_ur5_load_friction",), ur5_load_friction),
    **docs_tables_curve.TABLES,
    ("first_labels.md", "label_split_dev"): (("label_split_dev",), lambda: label_split("label_split_dev")),
    ("first_labels.md", "label_split_heldout"): (("label_split_heldout",),
                                                 lambda: label_split("label_split_heldout")),
}
