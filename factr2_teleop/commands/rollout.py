"""`factr2 rollout`: a trained policy drives a rig's follower through the same drivers, safety layer and
NEXT estimator as teleop; on a twin task the episodes are judged by the task's detectors (docs/rollout.md).

Keys (real rigs, or twins without --task; the terminal must be this process's): s = the next stage reached,
y = success, n = failure (each ends the episode), q = end the episode unlabelled and stop. Ctrl-C holds the
follower and stops.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from factr2_teleop.commands._twin_fault import add_twin_fault_argument, twin_faults
from factr2_teleop.session.read_back import read_back_lines
from factr2_teleop.session.teleop import message_lines

if TYPE_CHECKING:
    from factr2_teleop.session.rollout_report import RolloutResult

HELP = "roll a trained policy out on a rig (twin or real): episodes, success, stages, timing"


def add_arguments(parser) -> None:
    parser.add_argument("--rig", default="sim-piper", help="rig name or file (default: sim-piper)")
    parser.add_argument("--policy", required=True, type=Path,
                        help="RUN folder of factr2 train, or a step-*.json")
    parser.add_argument("--task", default=None, help="a twin task (factr2 tasks); without it the operator "
                        "marks stages and outcomes with keys")
    parser.add_argument("--episodes", type=int, default=1, help="episodes (default 1)")
    parser.add_argument("--seed", type=int, default=0,
                        help="episode k is placed with seed S * 100003 + k, as factr2 collect does: use a "
                        "seed your demonstrations did not (default 0)")
    parser.add_argument("--record", type=Path, default=None,
                        help="write the rollouts as one MCAP in this folder")
    parser.add_argument("--no-cameras", action="store_true",
                        help="record without the rig's cameras (a policy that looks still gets its frames)")
    parser.add_argument("--max-seconds", type=float, default=None,
                        help="episode time limit [s] (default: the task's)")
    parser.add_argument("--next", type=Path, default=None, help="a NEXT checkpoint other than the policy's "
                        "(used, and said)")
    parser.add_argument("--mode", default=None, help="estimator when the policy names no NEXT checkpoint "
                        "(default: the rig's)")
    parser.add_argument("--realtime", action="store_true", help="a twin in real time (timing), not lockstep")
    parser.add_argument("--schedule", choices=("ensemble", "receding"), default=None,
                        help="chunk execution (default: temporal ensembling, ACT and flow)")
    parser.add_argument("--ensemble-m", type=float, default=0.01, help="temporal ensembling weight exp(-m i)")
    parser.add_argument("--k-exec", type=int, default=None,
                        help="receding horizon: steps executed per chunk (default a third of the chunk)")
    parser.add_argument("--force", action="store_true", help="roll out on a task the policy's demonstrations "
                        "did not come from (refused without it)")
    parser.add_argument("--takeover", action=argparse.BooleanOptionalAction, default=None,
                        help="the leader follows the follower and the operator takes over by hand (torque "
                        "on the leader) or with the o key; the hand at rest or o hands back (default: on in "
                        "real time and on real rigs, off for a lockstep twin). With --task on a twin, the "
                        "scripted operator steps in when the policy stalls (SIMULATED)")
    parser.add_argument("--json", type=Path, default=None, help="write the summary JSON here")
    parser.add_argument("--force-input", choices=("live", "zero", "shuffle"), default="live",
                        help="the policy's force input: live (default), or ablated to measure its worth: "
                        "zero (0 N*m always), shuffle (drawn from the episode's own earlier forces)")
    add_twin_fault_argument(parser)


def summary_lines(out: RolloutResult) -> list[str]:
    import numpy as np

    t = out.timing
    sim = " (SIMULATED)" if out.simulated else ""
    lines = [f"rollout of {out.policy} on {out.rig}{sim}, task {out.task or '(operator-marked)'}, "
             f"seed {out.seed}, schedule {out.schedule}, feedback {out.feedback_mode}"]
    if out.note:
        lines.append(f"note: {out.note}")
    n = len(out.episodes)
    held = n if out.episodes_in_file is None else out.episodes_in_file  # the rates' denominator
    ok = sum(e["outcome"] == "success" for e in out.episodes)
    lines += [f"{'episodes':>26s}  {n}" + ("  (interrupted)" if out.interrupted else "")
              + (f"  ({held} in the file: the rates are over those)" if held != n else ""),
              f"{'success rate':>26s}  {ok} / {held} = {100 * out.success_rate:.1f} %",
              f"{'mean task progress':>26s}  {out.mean_progress:.2f}"]
    for s, r in out.stage_rates.items():
        lines.append(f"{'stage ' + s:>26s}  {100 * r:.0f} % reached")
    lines += [f"{'loop':>26s}  {t['loop_rate_hz']:.1f} Hz (target {t['loop_target_hz']:.0f}), period "
              f"p99 {t['period_p99_ms']:.2f} ms, max {t['period_max_ms']:.2f} ms, {t['overruns']} overruns / "
              f"{t['ticks']} ticks [{t['clock']}]",
              f"{'chunk latency':>26s}  mean {t['chunk_latency_mean_ms']:.1f} ms, "
              f"p99 {t['chunk_latency_p99_ms']:.1f} ms ({t['chunks']} chunks)",
              f"{'action age':>26s}  mean {t['action_age_mean_ms']:.1f} ms, "
              f"p99 {t['action_age_p99_ms']:.1f} ms",
              f"{'commands':>26s}  {t['commands_sent']} sent, {t['command_violations']} outside the "
              f"limits at the wire; chunks refused: {t['refused_nonfinite']} non-finite, "
              f"{t['refused_outside_limits']} outside the limits; holds {_holds(t['holds'])}",
              f"{'wall time':>26s}  {out.wall_s:.0f} s"]
    tk = out.takeover
    if tk:
        lat = tk["tracking_latency_ms"]
        err = tk.get("leader_tracking_err_rad")
        lines.append(f"{'takeovers':>26s}  {tk['takeovers']} ({', '.join(tk['by']) or 'none'}), operator "
                     f"{tk['operator_s']:.1f} s; successes without one {tk['autonomous_successes']} / {n}"
                     + (f"; latency to tracking mean {np.mean(lat):.0f} ms" if lat else ""))
        if err:
            lines.append(f"{'leader tracking error':>26s}  p50 {err['p50']:.4f} rad, p99 {err['p99']:.4f} "
                         f"rad, max {err['max']:.4f} rad")
    if out.recording:
        lines.append(f"{'recording':>26s}  {out.recording}")
    lines += read_back_lines(out.episodes, out.episodes_not_as_judged, out.recording_unread, 26)
    return lines + message_lines(out.messages)


def _holds(holds) -> str:
    """Follower holds by reason, in words: "6 (policy target outside the joint limits)", or "0"."""
    if not holds:
        return "0"
    if not isinstance(holds, dict):
        return str(holds)
    return ", ".join(f"{n} ({why})" for why, n in sorted(holds.items(), key=lambda kv: -kv[1]))


def _key_reader(marks, takeover_keys=None) -> threading.Thread | None:
    """Single keys from the terminal into `marks` (cbreak mode, restored at exit); None without a TTY."""
    if not sys.stdin.isatty():
        return None
    import atexit
    import termios
    import tty

    from factr2_teleop.session.takeover_switch import TOGGLE_KEY

    fd = sys.stdin.fileno()
    old = termios.tcgetattr(fd)
    tty.setcbreak(fd)
    atexit.register(termios.tcsetattr, fd, termios.TCSADRAIN, old)

    def read():
        while True:
            ch = sys.stdin.read(1)
            if not ch:
                return
            if ch.lower() in "synq":
                marks.put(ch.lower())
            elif takeover_keys is not None and ch.lower() == TOGGLE_KEY:
                takeover_keys.put(TOGGLE_KEY)

    th = threading.Thread(target=read, name="factr2-keys", daemon=True)
    th.start()
    return th


def run(args) -> int:
    import queue

    from factr2_teleop.session.rollout import RolloutHooks, RolloutOptions, run_rollout
    from factr2_teleop.session.takeover_switch import TOGGLE_KEY

    hooks = RolloutHooks(marks=queue.SimpleQueue())
    opts = RolloutOptions(rig=args.rig, policy=args.policy, task=args.task, episodes=args.episodes,
                          seed=args.seed, record=args.record, max_seconds=args.max_seconds, next=args.next,
                          realtime=args.realtime, mode=args.mode, schedule=args.schedule,
                          ensemble_m=args.ensemble_m, k_exec=args.k_exec, force=args.force,
                          takeover=args.takeover, faults=twin_faults(args),
                          record_cameras=not args.no_cameras, force_input=args.force_input)
    if args.force and args.task:
        from factr2_teleop.session.task_check import task_mismatch
        from policies.training.checkpoint import read_meta

        why = task_mismatch(read_meta(args.policy), args.task)
        if why:
            print(f"warning: {why}: rolled out anyway (--force)", file=sys.stderr)
    if args.takeover and args.task:
        from factr2_teleop.tasks.takeover_operator import TwinTakeoverOperator

        hooks.operator = TwinTakeoverOperator
    keys = hooks.takeover_keys if args.takeover is not False else None
    if (args.task is None or args.takeover) and _key_reader(hooks.marks, keys) is not None:
        marks_words = ("s = next stage reached, y = success, n = failure, q = stop; " if args.task is None
                       else "")
        take_words = f"{TOGGLE_KEY} = take over / hand back; " if keys is not None else ""
        print(f"keys: {marks_words}{take_words}Ctrl-C holds and stops")
    out = run_rollout(opts, hooks)
    for line in summary_lines(out):
        print(line)
    if args.json is not None:
        args.json.write_text(json.dumps(out.to_dict(), indent=1, default=float))
    return 130 if out.interrupted else 0
