"""What a session's closed recording holds, for its summary (`factr2 collect`, `factr2 rollout --record`, and
`factr2 recover FILE` later for a summary beside the file it rewrote). A
writer that stalled leaves a file recovered in place: its last episode without its stop ("incomplete"), the
episodes after it never started in it ("missing"). The summary then says each episode's outcome, task
progress and stages reached as the file holds them (the live verdict kept beside them as outcome_judged,
progress_judged, stages_judged), and its rates are over the episodes the file holds, so that they can be
reproduced from the file.

    in_file = read_back(results, mcap, status)   # results: EpisodeResult dicts, changed in place
    rates = episode_rates(results, stages)        # success_rate, mean_progress, stage_rates
    line = reread_summary(summary, mcap)          # a summary JSON's dict, after `factr2 recover FILE`
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from hardware.errors import UserError

JUDGED = ("outcome", "progress", "stages")  # what the file can say otherwise than the live judgement
MISSING = "missing"  # the outcome of an episode whose start never reached the file
# a summary's list of EpisodeResult dicts and its task-progress key: collect's JSON, rollout's JSON
SUMMARY_KINDS = (("results", "progress_mean"), ("episodes", "mean_progress"))


def file_episodes(mcap: Path) -> dict:
    """Episode index -> hardware.recording.reader.Episode as the written file holds it (its outcome
    "success", "failure", "unlabelled", "incomplete"; its progress marks), or one line saying why the file
    could not be read."""
    import warnings

    from hardware.recording.reader import Recording

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a truncated file warns; what it holds is what is asked
            return {e.index: e for e in Recording(mcap).episodes}
    except Exception as e:  # noqa: BLE001 -- said in the summary: the file is what failed, not the run
        return f"{type(e).__name__}: {e}"


def held_in_file(ep, judged: dict) -> dict:
    """What the file holds of an episode judged `judged` (its JUDGED keys) where `ep` is the file's Episode
    (None: not in the file). Its stop in the file carries the judged result; without it (incomplete), the
    progress is the last progress mark's value (0 without one) and a stage is reached when marked, at its
    time from the episode's start [s]; missing, nothing is reached."""
    if ep is not None and ep.outcome == judged.get("outcome"):
        return judged
    marks = ep.progress if ep is not None else []
    reached: dict = {}
    for t, _value, label in marks:
        reached.setdefault(label, round(t - ep.t_start, 3))
    values = [v for _t, v, _label in marks if np.isfinite(v)]
    stages = judged.get("stages")
    return {"outcome": MISSING if ep is None else ep.outcome, "progress": values[-1] if values else 0.0,
            "stages": {**{s: None for s in stages or {}}, **reached}}


def agree_with_file(results: list[dict], recorded: dict) -> list[int]:
    """Set each result's (EpisodeResult as a dict) outcome, progress and stages to the file's for its
    episode index (recorded: file_episodes), keeping the live verdict as <key>_judged where they differ (the
    judged value stays the one judged live when read back again); returns the indices whose outcome
    differs."""
    differ = []
    for r in results:
        judged = {k: r.get(f"{k}_judged", r[k]) for k in JUDGED if k in r}
        held = held_in_file(recorded.get(r["index"]), judged)
        for k, v in judged.items():
            r.pop(f"{k}_judged", None)
            r[k] = held[k]
            if held[k] != v:
                r[f"{k}_judged"] = v
        if r["outcome"] != judged["outcome"]:
            differ.append(r["index"])
    return differ


def read_back(results: list[dict], mcap: Path, status) -> dict:
    """The results (EpisodeResult dicts) made to say what the closed recording `mcap` holds (agree_with_file)
    and the summary's keys saying so: recording_error and recording_recovered (the RecorderStatus `status`),
    episodes_not_as_judged (indices), episodes_in_file (None: not read back), recording_unread (why the file
    could not be read, else None: then the results stay as judged)."""
    recorded = file_episodes(mcap)
    read = isinstance(recorded, dict)
    differ = agree_with_file(results, recorded) if read else []
    return {"recording_error": getattr(status, "error", None),
            "recording_recovered": bool(getattr(status, "recovered", False)),
            "episodes_not_as_judged": differ,
            "episodes_in_file": sum(r["outcome"] != MISSING for r in results) if read else None,
            "recording_unread": None if read else recorded}


def episode_rates(results: list[dict], stages=()) -> dict:
    """success_rate, mean_progress and stage_rates (share reaching each of `stages`) over the episodes the
    file holds (all of them when it was not read back: none is "missing"); 0 without any."""
    held = [r for r in results if r["outcome"] != MISSING]
    return {"success_rate": float(np.mean([r["outcome"] == "success" for r in held])) if held else 0.0,
            "mean_progress": float(np.mean([r["progress"] for r in held])) if held else 0.0,
            "stage_rates": {st: float(np.mean([r["stages"].get(st) is not None for r in held])) if held
                            else 0.0 for st in stages}}


def autonomous_successes(outcomes: list[str], takeovers: list[int]) -> int:
    """Episodes that succeeded with no takeover (outcomes and takeovers per episode, in order)."""
    return sum(1 for o, n in zip(outcomes, takeovers) if o == "success" and n == 0)


def read_back_lines(results: list[dict], not_as_judged: list[int] | None, unread: str | None,
                    width: int) -> list[str]:
    """The summary lines of read_back (none when the file holds what was judged), labels right-aligned in
    `width` characters."""
    by_index = {r["index"]: r for r in results}
    lines = []
    if not_as_judged:
        eps = ", ".join(f"{i} {by_index[i]['outcome']} (judged {by_index[i].get('outcome_judged')})"
                        for i in not_as_judged)
        lines.append(f"{'in the file':>{width}s}  episode {eps}: counted as the file holds them")
    if unread:
        lines.append(f"{'in the file':>{width}s}  not read back ({unread}): outcomes as judged")
    return lines


# -- a summary JSON read back again (`factr2 recover FILE` by hand) -----------------------------------------
def summary_episodes(summary, where: str) -> tuple[list[dict], str]:
    """A session summary's (collect's or rollout's JSON) list of episodes and its task-progress key;
    UserError (one line) when it is neither."""
    if isinstance(summary, dict):
        for key, progress in SUMMARY_KINDS:
            eps = summary.get(key)
            if isinstance(eps, list) and all(isinstance(r, dict) and isinstance(r.get("index"), int)
                                             and isinstance(r.get("outcome"), str) for r in eps):
                return eps, progress
    raise UserError("not a session summary (no results or episodes with index and outcome)", where=where,
                    fix="name the summary of `factr2 collect` or `factr2 rollout --json` with --summary, "
                        "or pass --no-summary")


def reread_summary(summary: dict, mcap: Path) -> str:
    """Make a session summary (the dict of collect's or rollout's JSON) say what the recording `mcap` holds,
    as the session's own read-back does (read_back, episode_rates, the takeover's autonomous successes), the
    recording marked recovered; returns one line saying what changed. UserError when the file cannot be read
    back (the summary is then left as it was)."""
    results, progress_key = summary_episodes(summary, str(mcap))
    work = [dict(r) for r in results]  # the summary changes only once the file was read
    was = {"success rate": summary.get("success_rate"), "task progress": summary.get(progress_key)}
    status = SimpleNamespace(error=summary.get("recording_error"), recovered=True)
    in_file = read_back(work, mcap, status)
    if in_file["recording_unread"]:
        raise UserError(f"cannot read it back ({in_file['recording_unread']}): summary left as it was",
                        where=str(mcap), fix="run `factr2 episodes show` on it")
    stage_rates = summary.get("stage_rates")
    rates = episode_rates(work, tuple(stage_rates) if isinstance(stage_rates, dict) else ())
    said = {r["index"]: r["outcome"] for r in results}  # before: the episodes whose outcome this read changes
    results[:] = work
    summary.update(in_file, success_rate=rates["success_rate"], **{progress_key: rates["mean_progress"]})
    if isinstance(stage_rates, dict):
        summary["stage_rates"] = rates["stage_rates"]
    tk = summary.get("takeover")
    if isinstance(tk, dict) and isinstance(tk.get("per_episode"), list):
        tk["autonomous_successes"] = autonomous_successes([r["outcome"] for r in work], tk["per_episode"])
    now = {"success rate": summary["success_rate"], "task progress": summary[progress_key]}
    by_index = {r["index"]: r for r in work}
    differ = [i for i in in_file["episodes_not_as_judged"] if said.get(i) != by_index[i]["outcome"]]
    parts = [("episode " + ", ".join(f"{i} {by_index[i]['outcome']} (judged {by_index[i]['outcome_judged']})"
                                     for i in differ))] if differ else []
    parts += [f"{k} {_num(was[k])} -> {_num(now[k])}" for k in now if was[k] != now[k]]
    return "; ".join(parts) if parts else "already said what the file holds"


def _num(x) -> str:
    return f"{x:.2f}" if isinstance(x, (int, float)) else str(x)
