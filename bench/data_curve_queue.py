"""The data curve's queue (bench/data_curve.py): where each collection part lies, and State, what OUT holds
(parts collected, points trained and rolled out) and which job can start next.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from bench import data_curve_ledger as ledger
from bench.data_curve_config import CurveConfig, parts_for, successful_ids
from bench.data_curve_report import point_dir
from bench.first_config import DATA_CURVE_PARTS_MAX, RIG


def part_dir(out: str | Path, task: str, k: int) -> Path:
    return Path(out) / task / "demos" / f"part{k:02d}"


def demos_root(cfg: CurveConfig) -> str:
    """The OUT whose collection this run trains on: its own, or --demos-from's."""
    return cfg.demos_from or cfg.out


def part_paths(cfg: CurveConfig, task: str, k: int) -> tuple[Path, Path]:
    """(recording, summary) of collection part k."""
    from factr2_teleop.tasks.run import CollectConfig, output_paths

    return output_paths(CollectConfig(rig=RIG, task=task, out=str(part_dir(demos_root(cfg), task, k)),
                                      seed=cfg.demo_seed + k), RIG)


class State:
    """What OUT holds (parts collected, points trained and rolled out) and what is planned."""

    def __init__(self, cfg: CurveConfig):
        self.cfg = cfg
        self.parts: dict = {t: {} for t in cfg.tasks}  # task -> {k: collection summary}
        # parts for 10 % more episodes than the largest point: a demonstrator failing up to 1 in 11 needs no
        # part more, which would start only when the others are in (the last points wait on it)
        self.planned = {t: math.ceil(max(cfg.points[t]) * 11 / (10 * cfg.part_episodes)) for t in cfg.tasks}
        self.trained: dict = {}
        self.rolled: dict = {}
        self.imported = ledger.read_imported(cfg.out)  # what the collection must match (--import-results)
        self.digest = ledger.next_digest(cfg) if self.imported else ""
        for t in cfg.tasks:
            for k in range(DATA_CURVE_PARTS_MAX):
                summary = part_paths(cfg, t, k)[1]
                if summary.is_file():
                    self.parts[t][k] = json.loads(summary.read_text())
                    self.planned[t] = max(self.planned[t], k + 1)
        for key in cfg.point_keys():
            run = point_dir(cfg.out, *key)
            for name, kept in (("train", self.trained), ("rollout", self.rolled)):
                if (run / f"{name}.json").is_file():
                    kept[key] = json.loads((run / f"{name}.json").read_text())

    def leading(self, task: str) -> list[int]:
        """The success counts of the parts collected without a gap from part 0."""
        out, k = [], 0
        while k in self.parts[task]:
            out.append(sum(r.get("outcome") == "success" for r in self.parts[task][k]["results"]))
            k += 1
        return out

    def named(self, task: str, k: int) -> list[tuple[str, dict]]:
        """(recording file name, collection summary) of the first k parts."""
        return [(part_paths(self.cfg, task, i)[0].name, self.parts[task][i]) for i in range(k)]

    def subset(self, task: str, n: int) -> tuple[list[Path], list[str]] | None:
        """(part folders, the first n successful episode ids) once the parts holding them are collected."""
        k = parts_for(self.leading(task), n)
        if k is None:
            return None
        ids = successful_ids(self.named(task, k))[:n]
        return [part_dir(demos_root(self.cfg), task, i) for i in range(k)], ids

    def plan_more(self, task: str) -> None:
        """Another part when every planned one is in and they hold fewer successes than the largest point."""
        need = max(self.cfg.points[task]) - sum(self.leading(task))
        if need > 0 and len(self.leading(task)) >= self.planned[task]:
            if self.planned[task] >= DATA_CURVE_PARTS_MAX:
                raise SystemExit(f"{task}: {DATA_CURVE_PARTS_MAX} parts hold fewer than "
                                 f"{max(self.cfg.points[task])} successful demonstrations; lower --points")
            self.planned[task] += 1

    def ready(self, running: set) -> list[tuple]:
        """Every job that can start now, first first: rollouts (they finish a point), then by (training seed,
        demonstrations): the small points of seed 0 first, a collection part before the point it completes,
        so a run stopped early leaves whole points."""
        cfg, jobs = self.cfg, []
        for t in cfg.tasks:  # the points imported were trained on the collection OUT holds, or it stops
            ledger.check_collection(t, self.imported, self.named(t, len(self.leading(t))), self.digest)
        for ti, t in enumerate(cfg.tasks if not cfg.demos_from else ()):  # --demos-from: collects nothing
            self.plan_more(t)
            for k in range(self.planned[t]):
                if k not in self.parts[t]:
                    jobs.append(((0, (k + 1) * cfg.part_episodes, 0, ti), "collect", (t, k)))
        for key in cfg.point_keys():
            t, n, s = key
            if key in self.rolled:
                continue
            if key in self.trained:
                jobs.append(((-1, n, s, 0), "rollout", key))
            elif (sub := self.subset(t, n)) is not None:
                jobs.append(((s, n, 1, cfg.tasks.index(t)), "train", (*key, *sub)))
        return [j for j in sorted(jobs, key=lambda j: j[0]) if (j[1], j[2][:3]) not in running]
