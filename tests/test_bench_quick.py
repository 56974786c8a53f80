"""Every benchmark in bench/ runs as `python -m bench.NAME --quick` (a few-second smoke run, its numbers mean
nothing), or is listed in SKIP with why it cannot be quick. A new script that is in neither list fails here.
Together about 80 s on the loaded 2-core VM."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench import harness

ROOT = Path(__file__).resolve().parents[1]

# script -> the arguments of its quick run beyond --quick ({tmp}: a scratch folder of the test)
QUICK = {
    "bench_arms_dynamics": [],
    "bench_can": [],
    "bench_dxl_fast_read": [],
    "bench_dynamixel": [],
    "bench_twin": ["--json", "{tmp}/twin.json"],
    "teleop_loop_timing": [],
    "bench_state_preset": ["--json", "{tmp}/state_preset.json"],
    "bench_recording": ["--out", "{tmp}"],
    "faults": ["--json", "{tmp}/faults.json"],
    "profile_tick": [],
    "teleop_twin_feedback": [],
    "bench_demo": ["--out", "{tmp}/demo"],
    "results_index": ["--check"],
    "docs_tables": ["--check"],
    "data_curve_advice": ["--check"],
}
# files each quick run writes as a bench/harness.py record
WRITES = {"bench_twin": "twin.json", "bench_state_preset": "state_preset.json", "bench_recording":
          "recording.json", "faults": "faults.json"}

SKIP = {
    "bench_first": "collects, trains and rolls out: its own --quick takes minutes "
                   "(tests/test_bench_first_inputs.py and tests/test_first_report.py cover its parts)",
    "first_curve": "needs a bench_first OUT folder with demonstrations, then trains",
    "first_force": "needs a `bench_first --table force` OUT folder; its ablations roll policies out",
    "first_label_dev": "needs a `bench_first` OUT folder; trains a policy and rolls three out",
    "portable": "a tool over committed result files, not a benchmark: tests/test_portable_results.py runs it",
    "force_history": "needs recorded demonstrations per task (`factr2 collect`)",
    "first_images_gpu": "needs a GPU (camera frames at the benchmark's size)",
    "bench_next": "trains NEXT for minutes on the real UR5 logs (absent from a fresh clone)",
    "bench_next_ur5": "the real UR5 logs (absent from a fresh clone)",
    "bench_payload_ur5": "the real UR5 logs (absent from a fresh clone)",
    "bench_urdf_ur5": "the real UR5 logs (absent from a fresh clone)",
    "next_ur5_experiments": "the real UR5 logs (absent from a fresh clone); trains dozens of models",
    "bench_diagnosis": "records twin logs and trains NEXT: tens of minutes",
    "bench_diagnosis_twin": "records twin logs per effect family and fits each: minutes",
    "bench_payload_imported": "records twin logs of an imported arm and fits them: minutes",
    "bench_springs_twin": "records twin logs per joint and spring: minutes",
    "tune_next_filter": "needs a `factr2 calibrate` checkpoint, then records pushed replays",
    "bench_policies": "trains image policies: minutes",
    "bench_teleop_record": "`factr2 teleop` with camera recording in a process of its own: 30 s and more",
    "label_truth": "needs recorded demonstrations per task",
    "lockstep_golden": "collects, trains and rolls out (the refactor check of issue #36/#52, run by hand)",
    "policy_path": "trains a policy and traces its imports",
    "takeover_twin": "needs a trained policy (--policy)",
    "profile_rollout": "needs a trained policy (--policy)",
    "slow_core": "needs a writable cgroup (root) to slow a core",
    "bring_data_round_trip": "tests/test_import_lerobot.py runs its digest; the round trip trains",
    "next_official_round_trip": "trains NEXT on an H5 file (20 s budget) and exports it",
    "faults_soak": "real time by design: its shortest run is one minute (--minutes 1)",
    "app_cpu_per_tick": "issue #53's tool, owned there; its small run is --ticks 50",
    "tick_instructions": "needs valgrind and a C compiler; runs each checkout under callgrind (minutes)",
    "data_curve": "collects, trains and rolls out: its own --quick takes minutes "
                  "(tests/test_data_curve.py covers its parts)",
    "val_vs_success": "needs training run folders (and their rollouts) to tabulate",
    "cap_wrist": "needs a cap-screw recording or a trained policy to trace "
                 "(tests/test_bench_cap_wrist.py covers its turn counter)",
}
# modules of bench/ that are not scripts (used by the ones above)
LIBRARIES = {"__init__", "harness", "first_config", "first_ledger", "first_report", "first_stages",
             "crash_trials", "fault_trials", "data_curve_report", "data_curve_config", "data_curve_defaults",
             "data_curve_ledger", "data_curve_queue", "docs_tables_pages", "docs_tables_curve",
             "first_images_workers"}


def scripts() -> set[str]:
    return {p.stem for p in (ROOT / "bench").glob("*.py")} - LIBRARIES


def test_every_script_is_quick_or_says_why_not():
    assert not set(QUICK) & set(SKIP)
    missing = scripts() - set(QUICK) - set(SKIP)
    assert not missing, f"bench scripts with neither a --quick run nor a reason in SKIP: {sorted(missing)}"
    assert not (set(QUICK) | set(SKIP)) - scripts(), "listed scripts that are gone"


def test_no_script_edits_sys_path():
    """`python -m bench.NAME` from the root finds bench and the packages; only the tools that import another
    checkout on purpose (--root) put it on the path."""
    for p in sorted((ROOT / "bench").glob("*.py")):
        text = p.read_text()
        if "sys.path.insert" in text:
            assert p.stem in ("app_cpu_per_tick", "tick_instructions", "profile_tick",
                              "profile_rollout"), p.name
            assert text.count("sys.path.insert") == 1 and ("args.root" in text or "a.root" in text), p.name


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(QUICK))
def test_quick_run(name, tmp_path):
    args = [a.replace("{tmp}", str(tmp_path)) for a in QUICK[name]]
    cmd = [sys.executable, "-m", f"bench.{name}", *(["--quick"] if "--check" not in args else []), *args]
    env = dict(os.environ, OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=180, env=env)
    assert r.returncode == 0, f"{' '.join(cmd)}\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
    if name in WRITES:
        rec = json.loads((tmp_path / WRITES[name]).read_text())
        assert harness.is_record(rec) and rec["machine"]["cores"]
        assert rec["command"].startswith(f"python -m bench.{name}")
