"""The wrist roll (joint 6) on cap-screw: the demonstrations' range and strokes, and where a rollout's policy
aims it beyond the joint limit (issue #51; SIMULATED). docs/tasks_cap_screw.md, "The wrist roll at its limit".

    python -m bench.cap_wrist demos REC.mcap [...]          joint 6 of every demonstration (state, command)
    python -m bench.cap_wrist trace TRACE.jsonl -- rollout ...  factr2 rollout, each chunk's joint 6 logged
    python -m bench.cap_wrist report TRACE.jsonl SUMMARY.json   per episode: chunks past the limit, when

The trace wraps ChunkSchedule.add and PolicyTarget.run (analysis only: the rollout itself is unchanged).
"""

from __future__ import annotations

import json
import sys
import warnings

import numpy as np

WRIST = 5  # joint 6, 0-based
STROKE_MIN_RAD = 0.3  # a clockwise run of the commanded wrist longer than this counts as a turn


def runs(x: np.ndarray, eps: float = 1e-3) -> list[float]:
    """Signed lengths [rad] of the monotone runs of x (a step under eps in either direction continues a
    run)."""
    out, cur = [], 0.0
    for d in np.diff(np.asarray(x, dtype=float)):
        if abs(d) < eps or cur == 0.0 or np.sign(d) == np.sign(cur):
            cur += d
        else:
            out.append(cur)
            cur = d
    if cur:
        out.append(cur)
    return out


def demos(paths: list[str]) -> None:
    from hardware.recording.schemas import joint_state_topic
    from policies.data.recordings import episode_id, follower_state_action, load_episodes

    warnings.simplefilter("ignore")
    eps, arms = load_episodes(paths)
    arm = arms.followers[0]
    qs, acts, turns = [], [], []
    for ep in eps:
        js = ep.topic(joint_state_topic(arm))
        grid = np.arange(js.t[0], js.t[-1], 1 / 30)
        st, ac = follower_state_action(ep, arm, grid, "read the wrist")
        ok = np.isfinite(ac[:, WRIST])
        q, a = st[ok, WRIST], ac[ok, WRIST]
        cw = [-r for r in runs(a) if r < -STROKE_MIN_RAD]
        turns.append(cw)
        qs.append(q)
        acts.append(a)
        print(f"{episode_id(ep)} {ep.outcome}: q6 {q.min():+.3f}..{q.max():+.3f}, commanded {a.min():+.3f}.."
              f"{a.max():+.3f} rad; clockwise turns [rad] {', '.join(f'{r:.2f}' for r in cw)}")
    q, a = np.concatenate(qs), np.concatenate(acts)
    n_cw = np.array([len(c) for c in turns])
    print(f"{len(eps)} episodes: q6 {q.min():+.3f}..{q.max():+.3f} rad, commanded {a.min():+.3f}.."
          f"{a.max():+.3f} rad (mean {a.mean():+.3f}, std {a.std():.3f}); "
          f"commanded > 2.0 rad: {(a > 2.0).mean():.4%}; "
          f"clockwise turns per episode {n_cw.min()}-{n_cw.max()}, total turned "
          f"{np.median([sum(c) for c in turns]):.2f} rad (median)")


def trace(path: str, argv: list[str]) -> int:
    from factr2_teleop.cli import main
    from factr2_teleop.session import rollout_pair
    from policies.rollout import schedule

    out = open(path, "w")
    add, run = schedule.ChunkSchedule.add, rollout_pair.PolicyTarget.run

    def traced_add(self, chunk):
        a = np.asarray(chunk.actions, dtype=float)[:self.executable_steps(len(chunk.actions))]
        why = add(self, chunk)
        out.write(json.dumps({"t": round(chunk.t_obs, 4), "q6_0": round(float(a[0, WRIST]), 4),
                              "q6_max": round(float(a[:, WRIST].max()), 4),
                              "q6_min": round(float(a[:, WRIST].min()), 4),
                              "refused": None if why is None else str(why)}) + "\n")
        return why

    def traced_run(self, now, objects=None, seed=None):
        out.write(json.dumps({"episode_start": round(now, 4), "seed": seed}) + "\n")
        return run(self, now, objects, seed)

    schedule.ChunkSchedule.add, rollout_pair.PolicyTarget.run = traced_add, traced_run
    try:
        return main(argv)
    finally:
        out.close()


def report(trace_path: str, summary_path: str, limit: float = 2.0944, into_s: float = 3.0) -> None:
    eps = json.load(open(summary_path))["episodes"]
    starts, chunks = [], []
    for line in open(trace_path):
        d = json.loads(line)
        if "episode_start" in d:
            starts.append(d["episode_start"])
            chunks.append([])
        elif chunks:
            chunks[-1].append(d)
    tot = np.zeros(4, dtype=int)  # chunks, past the limit, of those in the first into_s, refused
    for e, t0, cs in zip(eps, starts, chunks):
        cs = [c for c in cs if c["t"] - t0 <= e["duration_s"]]
        past = [c["t"] - t0 for c in cs if c["q6_max"] > limit]
        refused = [(round(c["t"] - t0, 1), c["q6_max"]) for c in cs if c["refused"]]
        last = [s for s, v in e["stages"].items() if v is not None]
        early = sum(t <= into_s for t in past)
        late = [round(t, 1) for t in past if t > into_s]
        tot += [len(cs), len(past), early, len(refused)]
        stage = last[-1] if last else "none"
        print(f"episode {e['index']} seed {e['seed']} {e['outcome']} (last stage {stage}, "
              f"{e['duration_s']:.0f} s): {len(cs)} chunks, {len(past)} aim joint 6 past {limit:.3f} rad "
              f"({early} in the first {into_s:.0f} s; later at {late} s), refused {refused}")
    print(f"all: {tot[0]} chunks, {tot[1]} past the limit ({tot[2]} in the first {into_s:.0f} s of an "
          f"episode), {tot[3]} refused")


if __name__ == "__main__":
    cmd, args = sys.argv[1], sys.argv[2:]
    if cmd == "demos":
        demos(args)
    elif cmd == "trace":
        sys.exit(trace(args[0], args[args.index("--") + 1:]))
    elif cmd == "report":
        report(args[0], args[1])
    else:
        print(f"unknown command {cmd!r}: demos, trace or report (see python -m bench.cap_wrist's docstring)",
              file=sys.stderr)
        sys.exit(2)
