"""Read recordings: file -> episodes -> numpy arrays per signal.

    rec = Recording("teleop.mcap")             # decodes once, then reads its array cache
    for ep in rec.episodes:
        js = ep.topic("/follower/joint_state")  # TopicArrays: js.t [s], js.fields["q"] (N, n) [rad]
        sig = ep.signals()                       # {"follower.joint.pos": (t, values), ...} own timestamps
                                                 # (twin tasks: "observation.state.objects", PRIVILEGED)
        grid = ep.resample(rate_hz=100.0)        # {"t": grid, "follower.joint.pos": (M, n), ...}
        log = ep.to_plain("follower")            # a hardware.recording.plain_log.PlainLog

Time base: every signal keeps its own timestamps (rig clock [s]). resample() puts them on one grid: float
signals by linear interpolation, bool/int signals (contact, status, overruns) by previous-value hold; grid
points outside a signal's span are NaN (float) or False/0 (bool/int) -- nothing is extrapolated.
A truncated file (recorder killed) reads with a warning; its last episode ends at the last sample and has
outcome "incomplete".
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hardware.recording import schemas as S
from hardware.recording.cache import Decoded, FrameIndex, LazyFields, TopicArrays, load_or_decode
from hardware.recording.mcap_scan import open_buffer, read_message_data
from hardware.recording.protobuf_wire import decode_compressed_image
from hardware.timeseries import hold_previous, interp_linear, resample, uniform_grid


def _slice(ta: TopicArrays, t0: float, t1: float) -> TopicArrays:
    a, b = np.searchsorted(ta.t, t0, side="left"), np.searchsorted(ta.t, t1, side="right")
    sliced = LazyFields({k: (lambda k=k: ta.fields[k][a:b]) for k in ta.fields})  # read on first use
    return TopicArrays(ta.topic, ta.schema, ta.t[a:b], sliced, ta.meta)


UNMARKED = "unmarked"  # the outcome of a recording without episode events: the whole file is one episode


@dataclass
class Episode:
    """One episode: [t_start, t_stop] on the rig clock [s]. outcome: "success", "failure", "discard",
    "unlabelled" (stopped, no verdict), "incomplete" (no stop: recorder killed) or UNMARKED (a file without
    episode events: the whole file)."""

    recording: Recording
    index: int
    t_start: float
    t_stop: float
    outcome: str
    task: str = ""
    events: list[dict] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return max(0.0, self.t_stop - self.t_start)

    @property
    def notes(self) -> list[str]:
        return [e["text"] for e in self.events if e["kind"] == "note"]

    @property
    def progress(self) -> list[tuple[float, float, str]]:
        """Task-progress marks (t [s], value in [0, 1], label)."""
        return [(e["t"], e["value"], e["text"]) for e in self.events if e["kind"] == "progress"]

    @property
    def topics(self) -> list[str]:
        return self.recording.topics

    def topic(self, name: str) -> TopicArrays:
        return _slice(self.recording.topic(name), self.t_start, self.t_stop)

    def frames(self, camera: str) -> Frames:
        return self.recording.frames(camera).between(self.t_start, self.t_stop)

    def signals(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Flat signal name ("follower.joint.pos", "leader.joint.tau_cmd", "loop.period", ...) ->
        (t [s], values), each on its own timestamps."""
        out = {}
        for name in self.recording.topics:
            ta = self.topic(name)
            schema = S.NUMERIC_SCHEMAS[ta.schema]
            for f in schema.fields:
                out[S.signal_name(name, schema.name, f.feature)] = (ta.t, ta.fields[f.name])
        return out

    def resample(self, t_grid: np.ndarray | None = None,
                 rate_hz: float | None = None) -> dict[str, np.ndarray]:
        """Every signal on one time grid (t_grid [s], or a uniform grid at rate_hz over the episode):
        float signals interpolated linearly, bool/int signals held (hardware.timeseries.resample, the
        resampler calibration and diagnosis use). Returns {"t": grid, name: values}."""
        if t_grid is None:
            if not rate_hz:
                raise ValueError("give t_grid or rate_hz")
            t_grid = uniform_grid(self.t_start, self.t_stop, rate_hz)
        t_grid = np.asarray(t_grid, dtype=float)
        kinds = {}
        for name in self.recording.topics:
            schema = S.NUMERIC_SCHEMAS[self.recording.topic(name).schema]
            for f in schema.fields:
                kinds[S.signal_name(name, schema.name, f.feature)] = f.kind
        out: dict[str, np.ndarray] = {"t": t_grid}
        for sig, (t, y) in self.signals().items():
            y = np.asarray(y, float) if kinds[sig] == "float" else np.asarray(y)  # cache.py: bool/int64 else
            out[sig] = resample(t, {sig: y}, t_grid=t_grid)[0][1][sig]
        return out

    def contact_share(self, arm: str = "follower") -> float:
        """Fraction of samples in contact: estimated contact, else the twin's ground truth (NaN: neither)."""
        for topic in (S.tau_ext_topic(arm), S.ground_truth_topic(arm)):
            if topic in self.recording.topics:
                c = self.topic(topic).fields["contact"]
                return float(np.mean(c)) if len(c) else float("nan")
        return float("nan")

    def to_plain(self, arm: str = "follower"):
        """This episode of `arm` as a PlainLog (the calibration input): t, q, qd, q_cmd, tau [N*m],
        temperature, joint_names, and from the twin's ground truth (held/interpolated onto t) tau_ext_true,
        force, contact. Estimated tau_ext (if recorded) goes to extra["tau_ext"]."""
        from hardware.recording.plain_log import PlainLog

        js = self.topic(S.joint_state_topic(arm))
        if len(js) < 2:
            raise ValueError(f"episode {self.index}: fewer than 2 {arm} joint-state samples")
        keep = np.concatenate([[True], np.diff(js.t) > 0])
        t = js.t[keep]
        f = {k: v[keep] for k, v in js.fields.items()}
        names = self.recording.joint_names(arm) or [f"joint{i + 1}" for i in range(f["q"].shape[1])]
        log = PlainLog(path=Path(f"{self.recording.path}#episode{self.index}.{arm}"), t=t, q=f["q"],
                       qd=f["q_dot"], q_cmd=f["q_cmd"], tau=f["tau_m"], units="N*m", joint_names=names,
                       temperature=f["temperature"])
        log.extra = {"current": f["current"], "status": f["status"], "gripper_pos": f["gripper_pos"]}
        if S.ground_truth_topic(arm) in self.recording.topics:
            gt = self.topic(S.ground_truth_topic(arm))
            log.tau_ext_true = interp_linear(gt.t, gt.fields["tau_ext_true"], t)
            log.force = interp_linear(gt.t, gt.fields["force"], t)
            log.contact = hold_previous(gt.t, gt.fields["contact"], t).astype(bool)
        if S.tau_ext_topic(arm) in self.recording.topics:
            te = self.topic(S.tau_ext_topic(arm))
            log.extra["tau_ext"] = interp_linear(te.t, te.fields["tau_ext"], t)
            log.extra["contact_est"] = hold_previous(te.t, te.fields["contact"], t)
        return log


class Frames:
    """A camera's frames: t [s]; jpeg(i) -> bytes; rgb(i) -> H x W x 3 uint8."""

    def __init__(self, path: Path, index: FrameIndex, sel: slice = slice(None)):
        self.path, self._index = path, index
        self.t = index.t[sel]
        self._loc = index.loc[sel]
        self._chunk: dict = {}

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def between(self, t0: float, t1: float) -> Frames:
        """Frames with t0 <= t <= t1, within 1 us (frame times come from ns log times; sample times are
        float seconds, so a frame taken at an episode's start tick may differ from it by < 1 ns)."""
        order_t = self._index.t
        return Frames(self.path, self._index, slice(np.searchsorted(order_t, t0 - 1e-6, "left"),
                                                    np.searchsorted(order_t, t1 + 1e-6, "right")))

    def jpeg(self, i: int) -> bytes:
        buf, close = open_buffer(self.path)
        try:
            _, data, _, _ = decode_compressed_image(read_message_data(buf, self._loc[i], self._chunk))
            return bytes(data)
        finally:
            close()

    def rgb(self, i: int) -> np.ndarray:
        import io

        from PIL import Image

        return np.asarray(Image.open(io.BytesIO(self.jpeg(i))).convert("RGB"))


class Recording:
    """One MCAP recording. use_cache: read/write its array cache (cache.py)."""

    def __init__(self, path: str | Path, *, use_cache: bool = True, write_cache: bool = True):
        self.path = Path(path)
        self._d: Decoded = load_or_decode(self.path, use_cache=use_cache, write_cache=write_cache)
        for w in self._d.warnings:
            warnings.warn(f"{self.path}: {w}", stacklevel=2)

    @property
    def truncated(self) -> bool:
        return self._d.truncated

    @property
    def warnings(self) -> list[str]:
        return list(self._d.warnings)

    @property
    def from_cache(self) -> bool:
        return self._d.from_cache

    @property
    def metadata(self) -> dict[str, dict[str, str]]:
        return self._d.metadata

    @property
    def info(self) -> dict[str, str]:
        """The recording metadata (hardware/recording/metadata.py): rig, arms, software, operator, ..."""
        return self._d.info

    @property
    def topics(self) -> list[str]:
        return sorted(self._d.topics)

    @property
    def cameras(self) -> list[str]:
        return sorted(self._d.frames)

    @property
    def events(self) -> list[dict]:
        return list(self._d.events)

    def topic(self, name: str) -> TopicArrays:
        if name not in self._d.topics:
            raise KeyError(f"{self.path}: no topic {name!r} (has: {', '.join(self.topics)})")
        return self._d.topics[name]

    def frames(self, camera: str) -> Frames:
        if camera not in self._d.frames:
            raise KeyError(f"{self.path}: no camera {camera!r} (has: {', '.join(self.cameras) or 'none'})")
        return Frames(self.path, self._d.frames[camera])

    def joint_names(self, arm: str) -> list[str]:
        ta = self._d.topics.get(S.joint_state_topic(arm))
        names = (ta.meta.get("joint_names", "") if ta else "").split(",")
        return [n for n in names if n]

    def task_object_names(self, topic: str = S.TOPIC_TASK_OBJECTS) -> list[str]:
        """Element names of an object vector: the PRIVILEGED task-object vector (/task/objects, read back as
        "observation.state.objects") or, topic S.TOPIC_PERCEIVED, the SIMULATED perceived one (twin only);
        [] when the recording has none."""
        ta = self._d.topics.get(topic)
        return [n for n in (ta.meta.get("joint_names", "") if ta else "").split(",") if n]

    def time_span(self) -> tuple[float, float]:
        """(first, last) sample time [s] over all topics and cameras; (nan, nan) when empty."""
        ts = [a.t for a in self._d.topics.values() if len(a)]
        ts += [f.t for f in self._d.frames.values() if len(f.t)]
        if not ts:
            return float("nan"), float("nan")
        return float(min(t[0] for t in ts)), float(max(t[-1] for t in ts))

    @property
    def episodes(self) -> list[Episode]:
        t_first, t_last = self.time_span()
        evs = self._d.events
        starts = [e for e in evs if e["kind"] == "start"]
        if not starts:
            return [Episode(self, 0, t_first, t_last, UNMARKED, "", list(evs))]
        eps = []
        for s in starts:
            idx = s["episode"]
            mine = [e for e in evs if e["episode"] == idx]
            stops = [e["t"] for e in mine if e["kind"] == "stop"]
            labels = [e["kind"] for e in mine if e["kind"] in S.OUTCOME_KINDS]
            if labels:
                outcome = labels[-1]
            else:
                outcome = "unlabelled" if stops else "incomplete"
            t_stop = stops[-1] if stops else t_last
            eps.append(Episode(self, idx, s["t"], max(s["t"], t_stop), outcome, s["text"], mine))
        return eps


def open_when_finished(path: str | Path, wait_s: float = 15.0, poll_s: float = 0.2) -> Recording:
    """The recording once its writer process has finished it (a killed app's writer outlives it and drains
    its rings first: read at once, the file is still truncated), or as it is after wait_s [s, wall].
    No array cache is read or written; the truncated file's warnings are not repeated while waiting."""
    import time

    end = time.monotonic() + wait_s
    while True:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                rec = Recording(path, use_cache=False, write_cache=False)
            if not rec.truncated or time.monotonic() > end:
                return rec
        except Exception:  # noqa: BLE001 -- not written yet (the writer starts, drains, finishes)
            if time.monotonic() > end:
                raise
        time.sleep(poll_s)
