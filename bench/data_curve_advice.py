"""What the installed app cites when it advises a run (policies/training/advice.py): the measured data curve's
per-point summary and what training shorter did to success, made from the committed results so the package
never holds a hand copy. The wheel ships policies/training/data_curve_points.json; results/ is not in it.

    python -m bench.data_curve_advice            # write the package copy from results/
    python -m bench.data_curve_advice --check    # exit 1 when the package copy differs from results/

Sources: results/data_curve_current.json (`python -m bench.data_curve --out OUT --report --results
data_curve_current`: per task and number of demonstrations, every training seed present pooled) and
results/first_curve_{peg-insert,press-fit}.json (`python -m bench.first_curve`: success against training
steps, one training run per task). Run it again whenever either is rewritten (more seeds, more points);
tests/test_training_advice.py fails until it is.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bench import harness
from bench.first_config import RIG
from bench.first_report import fisher_less, wilson

PACKAGE_COPY = harness.ROOT / "policies" / "training" / "data_curve_points.json"
CURVE = "data_curve_current"  # results/NAME.json
SHORTER = ("first_curve_peg-insert", "first_curve_press-fit")  # success against training steps


def curve_points(payload: dict) -> dict:
    """Per task, its points in order of demonstrations: the training seeds present pooled (successes over
    all their rollouts) with the 95 % Wilson interval."""
    by = {}
    for r in payload["rows"]:
        by.setdefault((r["task"], int(r["n_demos"])), []).append(r)
    tasks: dict = {}
    for (task, n), rows in sorted(by.items()):
        k = sum(int(s) for r in rows for s in r["successes"])
        episodes = sum(len(r["successes"]) for r in rows)
        lo, hi = wilson(k, episodes)
        tasks.setdefault(task, []).append({
            "n": n, "seeds": sorted(int(r["seed"]) for r in rows),
            "rollouts": sorted({len(r["successes"]) for r in rows}),  # per training seed
            "k": k, "episodes": episodes, "wilson": [round(lo, 4), round(hi, 4)]})
    return tasks


def shorter_training(payloads: list[dict]) -> dict:
    """Success of the evaluated (EMA) weights at the shortest and the longest step every curve shares,
    pooled over the tasks, and the one-sided Fisher p that the shorter is lower by chance."""
    shared = set.intersection(*({r["step"] for r in p["rows"] if r.get("ema", True)} for p in payloads))
    steps = sorted(shared)
    short, long_ = steps[0], steps[-1]

    def pooled(step: int) -> tuple[int, int]:
        rows = [r for p in payloads for r in p["rows"] if r["step"] == step and r.get("ema", True)]
        return sum(sum(r["success"]) for r in rows), sum(len(r["success"]) for r in rows)

    (ks, ns), (kl, nl) = pooled(short), pooled(long_)
    return {"tasks": [p["config"]["task"] for p in payloads], "short_steps": short, "long_steps": long_,
            "k_short": ks, "n_short": ns, "k_long": kl, "n_long": nl,
            "p_one_sided": round(fisher_less(ks, ns, kl, nl), 4),
            "sources": [f"results/{name}.json" for name in SHORTER],
            "docs": "docs/policies.md, 'Choosing the defaults'"}


def build(results: Path = harness.RESULTS) -> dict:
    """The package copy's content from the result files under `results`."""
    rec = harness.load(results / f"{CURVE}.json")
    p = rec["payload"]
    shorter = [harness.load(results / f"{name}.json")["payload"] for name in SHORTER]
    return {"written_by": "python -m bench.data_curve_advice",
            "source": f"results/{CURVE}.json", "source_command": rec["command"],
            "simulated": bool(p["simulated"]), "observation": p["observation"], "defaults": p["defaults"],
            "rig": RIG, "docs": "docs/policies.md, 'The data curve'",
            "tasks": curve_points(p), "shorter_training": shorter_training(shorter)}


def text(content: dict) -> str:
    return json.dumps(content, indent=1) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when the package copy differs from results/")
    ap.add_argument("--quick", action="store_true", help="the same (it takes a second)")
    a = ap.parse_args(argv)
    return harness.write_or_check(PACKAGE_COPY, text(build()), a.check, "python -m bench.data_curve_advice")

if __name__ == "__main__":
    sys.exit(main())
