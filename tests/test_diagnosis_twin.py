"""Diagnosis closes the loop on twin data (SIMULATED): an effect injected through the twin's undeclared-effect
hook is found on the right joint with the right period and halves that joint's held-out error; with nothing
injected, nothing is added. sim-piper in lockstep through the real Piper driver (calibration/diagnosis/
twin_data.py); the full family table is bench/bench_diagnosis_twin.py -> docs/diagnosis_twin.md.

Data (generated once per session, ~75 s on 2 shared cores): a first-pass pair with nothing injected
(train seed 0, 60 s -- 30 s is almost all single-joint sweeps, too little multi-joint motion to pin a
period down; held out seed 100, 30 s) whose findings are declared for the later runs, the same
trajectories with a position-periodic load 0.3 N*m * sin(2 pi q2 / 0.35 + 0.4) on joint 2, and a fresh
40 s run (seed 1, last quarter held out) with nothing injected.
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration.diagnosis.greybox import errors
from calibration.diagnosis.report import to_json
from calibration.diagnosis.twin_data import (
    CLEAN_EFFECTS,
    TWIN_CASES,
    diagnose_logs,
    first_pass,
    generate,
    record,
)


@pytest.fixture(scope="session")
def twin_logs(tmp_path_factory):
    from hardware.recording.plain_log import save_plain_log

    root = tmp_path_factory.mktemp("diag_twin")
    base = generate(root / "none", TWIN_CASES["none"], seconds=60, heldout_seconds=30)
    periodic = generate(root / "periodic", TWIN_CASES["position_periodic"], seconds=60, heldout_seconds=30)
    fresh = save_plain_log(root / "fresh.npz", **record(40, 1, None, CLEAN_EFFECTS, twin_seed=1))
    return {"base": base, "periodic": periodic, "fresh": fresh}


@pytest.fixture(scope="session")
def declared(twin_logs):
    base = twin_logs["base"]
    return first_pass(diagnose_logs([base[0]], [base[1]]))


def test_logs_are_plain_twin_logs(twin_logs):
    d = np.load(twin_logs["periodic"][0])
    assert {"t", "q", "qd", "q_cmd", "tau_m", "current"} <= set(d.files)
    assert d["q"].shape[1] == 6 and d["t"][-1] > 25.0
    assert bool(d["simulated"])
    # the hook's load shows in tau_m: same trajectory and seed with and without it differ on joint 2 only
    b = np.load(twin_logs["base"][0])
    n = min(len(b["t"]), len(d["t"]))
    diff = np.abs(d["tau_m"][:n] - b["tau_m"][:n]).mean(0)
    assert np.argmax(diff) == 2 and diff[2] > 0.1


def test_periodic_injection_is_found_on_its_joint(twin_logs, declared):
    case = TWIN_CASES["position_periodic"]
    tr, he = twin_logs["periodic"]
    dg = diagnose_logs([tr], [he], declared=declared)
    first = dg.steps[1].added
    assert (first["effect"], first["joint"]) == ("position_periodic", 2), first
    period = first["hyper"]["period_rad"]
    assert abs(period / case.params["period_rad"] - 1) <= 0.05, period
    assert abs(first["params"]["amplitude"] - 0.3) <= 0.06, first["params"]
    l1_after, _ = errors(dg.heldout.y, dg.model.predict(dg.heldout))
    before = dg.steps[0].heldout_l1[2]
    assert l1_after[2] <= 0.5 * before, (before, l1_after[2])


def test_no_injection_adds_nothing(twin_logs, declared):
    dg = diagnose_logs([twin_logs["fresh"]], [], declared=declared)
    assert dg.found() == [], [e.to_json() for e in dg.found()]
    rep = to_json(dg, {"units": "N*m"})
    assert rep["verdict"].startswith("the model explains the data")
    # every candidate it tried fell below the acceptance threshold on held-out data
    assert all(r["heldout_gain"] <= r["needed"] for r in dg.rejected)
