"""One training run end to end: recordings -> phase labels -> dataset -> model -> train, with every check on
the user's input done before RUN is written (a bad input leaves nothing behind)."""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from calibration.next.ident import format_ids
from hardware.errors import UserError
from hardware.recording import schemas as S
from hardware.recording.cache import cache_key
from hardware.recording.metadata import software_version
from policies.data.dataset import build_dataset
from policies.data.perturbed import DEFAULT_PERTURBED
from policies.data.recordings import (
    describe_rig,
    episode_id,
    load_episodes,
    recorded_next_checkpoints,
    skipped_line,
    training_episodes,
)
from policies.data.sampler import format_ratio
from policies.labels.labelling import load_next, phases_identity, resolve_thresholds
from policies.labels.phases import labels_warning
from policies.models.config import PolicyConfig
from policies.training import checkpoint as C
from policies.training.methods import METHODS
from policies.training.regularise import run_inputs
from policies.training.run_config import RESUME_KEYS, RunOptions
from policies.training.train import Dist, TrainHooks, barrier, train


def data_hash(episodes) -> str:
    """Recordings (size + head/tail hash, not the path or mtime) and episode spans."""
    h = hashlib.sha256()
    for ep in episodes:
        key = cache_key(ep.recording.path)
        h.update(json.dumps([key["size"], key["head_tail_sha256"], ep.index, ep.t_start, ep.t_stop]).encode())
    return h.hexdigest()[:16]


# TrainConfig entries added after runs were made, with the value those runs had
ADDED_TRAIN = {"train.precision": "auto", "train.ema": True, "train.obs_noise": None, "train.keep": "last"}


def _entry(meta: dict, key: str):
    """meta's entry `key` ("train.lr": nested); the model config with the defaults of fields added since."""
    if key == "policy":
        return PolicyConfig.from_dict(meta.get("policy", {})).to_dict()
    if key in ADDED_TRAIN:  # runs from before the choice: its default (precision: precision_used says more)
        return (meta.get("train") or {}).get(key[len("train."):], ADDED_TRAIN[key])
    if key == "actions":  # runs from before the choice learned absolute targets
        return meta.get("actions", "absolute")
    if key == "perturbed":  # runs from before the choice: the default (their data had no perturbed tick)
        return meta.get("perturbed", DEFAULT_PERTURBED)
    if key == "phases":  # the thresholds and their kind of source; the source's message is for people
        ph = meta.get("phases")
        return phases_identity(ph) if isinstance(ph, dict) else ph
    for part in key.split("."):
        meta = meta.get(part) if isinstance(meta, dict) else None
    return meta


def _compare(old: dict, new: dict) -> list[str]:
    """The RESUME_KEYS entries (policies.training.run_config: from the options' fields) in which two metas
    differ."""
    return [k for k in RESUME_KEYS
            if json.dumps(_entry(old, k), sort_keys=True) != json.dumps(_entry(new, k), sort_keys=True)]


def _check_out(o: RunOptions):
    out = Path(o.out)
    last = C.last_checkpoint(out)
    if o.resume and last is None:
        raise UserError(
            "--resume: no checkpoint in this folder",
            where=str(out),
            fix="drop --resume to start a new run, or name the folder of an earlier run",
        )
    if not o.resume and (last is not None or (out / "metrics.jsonl").exists()):
        raise UserError(
            "this folder already holds a training run",
            where=str(out),
            fix="pass --resume to continue it, or another --out",
        )
    return last


def _load(o: RunOptions):
    """The run's episodes (only those o.episodes names, when it names some), their arm set, and the
    episodes skipped as failed or incomplete ([{"episode": id, "why": ...}])."""
    episodes, arms = load_episodes(o.inputs, lerobot_map=o.lerobot_map or None)
    if o.episodes is not None:
        keep = set(o.episodes)
        missing = keep - {episode_id(e) for e in episodes}
        if missing:  # a mistyped id must not train silently on fewer episodes
            raise UserError(f"{len(missing)} chosen episode(s) not in the recordings, e.g. {min(missing)}",
                            where=", ".join(map(str, o.inputs)),
                            fix="name them as `factr2 episodes list` does: FILE.mcap#N (none discarded)")
        episodes = [e for e in episodes if episode_id(e) in keep]
        if not episodes:
            raise UserError("none of the chosen episodes is usable", where=", ".join(map(str, o.inputs)),
                            fix="choose episodes that are not discarded")
    kept, skipped = training_episodes(episodes, include_failed=o.include_failed,
                                      keep_incomplete=o.keep_incomplete)
    if not kept:
        raise UserError(
            f"no episode to train on: {skipped_line(skipped)}",
            where=", ".join(map(str, o.inputs)),
            fix="collect successful demonstrations, or pass the flag named to train on these",
        )
    return kept, arms, skipped


def precheck(o: RunOptions) -> None:
    """The cheap checks, once, before worker processes start (--nproc): folder, recordings, thresholds."""
    _check_out(o)
    episodes, arms, _ = _load(o)
    _thresholds(o.resolved(), load_next(o.next) if o.next is not None else None, episodes, arms)


NO_FORCE_PHASES = {"source": "none: no force-like signal in the recordings, every sample free",
                   "source_kind": None}


def _thresholds(o: RunOptions, next_model, episodes, arms):
    """The contact thresholds, or None for episodes without any force-like signal (no tau_ext, motor torque
    or current: a LeRobotDataset without them, GELLO saves) and no --next: their samples are all free, and a
    method that needs a force input or FIRST's re-sampling is refused here with the reason."""
    def logged(field: str) -> bool:
        return any(np.isfinite(ep.topic(S.joint_state_topic(a)).fields[field]).any()
                   for ep in episodes for a in arms.followers)

    if next_model is not None:
        field = "current" if next_model.ck.units == "A" else "tau_m"  # what NEXT runs on (its units)
        if not logged(field):
            raise UserError(
                f"--next runs NEXT over the logged motor {'current' if field == 'current' else 'torque'}, "
                "and these episodes have none (GELLO saves, LeRobot data without effort)",
                where=", ".join(map(str, o.inputs)),
                fix="train a base method (--method base) without --next (docs/bringing_data.md)")
        return resolve_thresholds(o.thresholds, next_model, episodes, arms)
    if any(S.tau_ext_topic(arms.followers[0]) in ep.recording.topics for ep in episodes) or logged(
            "tau_m") or logged("current"):  # the labels' own line asks for --next where tau_ext is missing
        return resolve_thresholds(o.thresholds, next_model, episodes, arms)
    m = METHODS[o.method]
    if m.force or len(set(o.ratio)) > 1:
        raise UserError(
            f"--method {o.method}" + (f" --ratio {format_ratio(o.ratio)}" if not m.force else "")
            + " needs FIRST phase labels or a force input, and these episodes have no force-like signal "
            "(no tau_ext, effort or current)",
            where=", ".join(map(str, o.inputs)),
            fix="train a base method (--method base), or bring data with joint effort or motor current "
            "(docs/bringing_data.md)")
    return None


def prepare(o: RunOptions, d: Dist):
    """Everything before training: (data, policy config, resolved options, meta, resume checkpoint)."""
    o = o.resolved()  # the method's ratio and force, the preset, the model fields the preset fills
    tcfg = o.train
    out = Path(o.out)
    last = _check_out(o)
    if tcfg.batch % d.world:
        raise UserError(
            f"batch {tcfg.batch} is not a multiple of the {d.world} processes",
            fix="choose --batch divisible by --nproc",
        )
    episodes, arms, skipped = _load(o)
    next_model = load_next(o.next) if o.next is not None else None
    th = _thresholds(o, next_model, episodes, arms)
    pcfg = o.policy_config()

    def build():
        return build_dataset(episodes, arms, th=th, chunk=pcfg.chunk, image_size=pcfg.image_size,
                             force=o.force, rate_hz=o.rate_hz, next_model=next_model,
                             val_fraction=o.val_fraction, seed=tcfg.seed, observation=o.observation,
                             action_frame=o.actions, perturbed=o.perturbed)

    # rank 0 decodes the frame caches first, the others then read them; an input error on rank 0 still
    # reaches the barrier, and the others then meet the same error themselves (nobody waits forever)
    data, err = None, None
    if d.main:
        try:
            data = build()
        except UserError as e:
            err = e
    barrier(d)
    if err is not None:
        raise err
    if not d.main:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = build()
    train_idx, _ = data.split()
    if len(train_idx) < 1:
        raise UserError("no training samples", where=str(o.inputs[0]), fix="record more episodes")
    lacking = sorted(set(tcfg.obs_noise or {}) - run_inputs(data))
    if lacking:  # noise asked on an input this run does not have would silently do nothing
        raise UserError(f"--obs-noise names {', '.join(lacking)}, not an input of this run "
                        f"(it has {', '.join(sorted(run_inputs(data)))})", where="--obs-noise",
                        fix="name only the run's inputs")
    # the model's input and output sizes: the data's
    pcfg = replace(pcfg, n_cameras=len(data.names.cameras), state_dim=data.state.shape[1],
                   action_dim=data.action.shape[2], force_dim=data.force.shape[1],
                   objects_dim=data.objects.shape[1] if data.objects is not None else 0)
    o = replace(o, rate_hz=data.rate_hz)
    named_next = next((ids for ids in map(recorded_next_checkpoints, episodes) if ids), ())
    meta = {
        **o.to_meta(pcfg),  # the configuration (policies.training.run_config)
        "features": data.names.to_dict(),
        "preprocess": data.pre.to_dict(),  # normaliser + image path: the rollout rebuilds exactly this
        "phases": th.to_dict() if th is not None else NO_FORCE_PHASES,
        "next_checkpoint": str(next_model.id) if next_model is not None else format_ids(named_next),
        "tau_ext_source": "offline" if next_model is not None else "recorded",
        # the estimator behind a recorded tau_ext (its recording's feedback mode: next, dob): rollout feeds
        # the policy the same one (factr2_teleop/session/rollout.py)
        "tau_ext_estimator": "next" if next_model is not None else _recorded_estimator(episodes),
        "data_hash": data_hash(episodes),
        "episodes": data.episode_ids,
        "val_episodes": [data.episode_ids[i] for i in data.val_episodes],
        # left out by default (failed demonstrations, episodes cut off), and the flags that kept the others
        "skipped_episodes": skipped,
        "tasks": _tasks(episodes),  # what rollout checks its --task against (session/task_check.py)
        "samples": {"train": int(len(train_idx)), "val": int(len(data) - len(train_idx)),
                    "perturbed": int(data.perturbed.sum()) if data.perturbed is not None else 0},
        # what the sampler re-weights: the training split's share of each phase (free, pre-contact, contact)
        "phase_shares": dict(zip(("free", "pre_contact", "contact"), map(float, _shares(data)))),
        "rig": describe_rig(episodes[0]),
        "arms": arms.to_dict(),
        "software_version": software_version(),
        "torch": torch.__version__,
        "world_size": d.world,
    }
    if o.resume:
        old = C.read_meta(last)
        diff = _compare(old, meta)
        if diff:
            raise UserError(
                f"--resume: this folder's run has another configuration ({', '.join(diff)})",
                where=str(out),
                fix="resume with the same options and recordings, or use another --out",
            )
    return data, pcfg, o, meta, (last if o.resume else None)


def run_training(o: RunOptions, d: Dist, stop_at: int | None = None, on_progress=None, stop=None) -> dict:
    """stop_at / on_progress / stop: policies.training.train.TrainHooks (an app's progress view and stop
    button)."""
    data, pcfg, o, meta, resume_from = prepare(o, d)
    if d.main:
        Path(o.out).mkdir(parents=True, exist_ok=True)
        if meta["skipped_episodes"]:
            print(skipped_line(meta["skipped_episodes"]))
        n_tr = meta["samples"]["train"]
        print(
            f"{len(data.episode_ids)} episodes, {n_tr} training / {meta['samples']['val']} validation "
            "samples "
            f"at {data.rate_hz:.3g} Hz, {_inputs(data)}; phases F/PC/C "
            f"{' / '.join(f'{x:.0%}' for x in _shares(data))}; method {o.method}, ratio "
            f"{format_ratio(o.ratio)}, force {o.force}; {d.world} process(es) on {d.device}"
            + _sources(data, o.source_weights)
            + (f"; {meta['samples']['perturbed']} perturbed samples ({o.perturbed}: "
               + ("the operator's target learned" if o.perturbed == "dart" else "their actions masked") + ")"
               if meta["samples"]["perturbed"] else "")
        )
        warn = labels_warning(_shares(data))
        if warn:
            print(warn)
    with data:  # the data's crop threads end with the run
        return train(data, pcfg, o, meta, d, resume_from, TrainHooks(stop_at, on_progress, stop))


def _recorded_estimator(episodes) -> str:
    """The feedback mode(s) of the episodes' recordings (next, dob; "dob,next" when mixed; "" none)."""
    named = (str(ep.recording.info.get("feedback_mode", "")) for ep in episodes)
    modes = {m for text in named for m in text.split(",") if m}
    return ",".join(sorted(modes))


def _tasks(episodes) -> dict:
    """Task name -> number of training episodes (the episode's, else its recording's; unnamed left out)."""
    out: dict = {}
    for ep in episodes:
        name = ep.task or ep.recording.info.get("task", "")
        if name:
            out[name] = out.get(name, 0) + 1
    return out


def _inputs(data) -> str:
    """What the policy sees besides joints and force, for the start-of-run line."""
    parts = [f"cameras {', '.join(data.names.cameras)}"] if data.names.cameras else []
    if data.objects is not None:
        perceived = data.names.objects_feature == S.PERCEIVED_FEATURE
        what = "perceived objects (simulated camera detector, " if perceived else "PRIVILEGED object state ("
        parts.append(f"{what}{data.objects.shape[1]} values, SIMULATED)")
    return ", ".join(parts) or "joints and force only"


def _sources(data, weights) -> str:
    """"; samples by source demo/policy/pre/operator N/N/N/N, weights ..." for rollout data ("" else)."""
    if data.source is None:
        return ""
    import numpy as np

    from hardware.recording.interventions import SOURCE_NAMES

    n = np.bincount(data.source[data.split()[0]].astype(np.int64), minlength=4)[:4]
    return (f"; samples by source {'/'.join(SOURCE_NAMES)} {'/'.join(str(int(k)) for k in n)}, weights "
            f"{'/'.join(f'{w:g}' for w in weights)}")


def _shares(data):
    from policies.labels.phases import phase_shares

    return phase_shares(data.phase[data.split()[0]])
