"""Policy checkpoints: RUN/checkpoints/step-NNNNNNN.safetensors (weights, no pickle) + .json (policy config,
train config, method, features, preprocess, phase thresholds, NEXT checkpoint id, data hash, rig and arm,
software version, metrics) + .optim.safetensors (AdamW moments: what `--resume` needs to continue exactly).
RUN/checkpoints/last names the newest complete one (written last, so a crash never points at half a file):
what --resume continues. A run trained with --keep val-min also keeps valmin-NNNNNNN.* (the weights at its
lowest validation loss) and RUN/checkpoints/kept naming them: what a RUN folder loads for use.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from hardware.errors import ConfigError, UserError
from policies.data.preprocess import Preprocess
from policies.models.config import PolicyConfig
from policies.models.policy import make_policy

FORMAT = "factr2-policy/1"
KEEP = 2  # older periodic checkpoints beyond this many are removed (the final one always stays)


def _optim_tensors(opt: torch.optim.Optimizer) -> dict[str, torch.Tensor]:
    out = {}
    for pid, st in opt.state_dict()["state"].items():
        for k, v in st.items():
            out[f"{pid}.{k}"] = (v if torch.is_tensor(v) else torch.tensor(v)).detach().cpu().contiguous()
    return out


def _write_atomic(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    write(tmp)
    os.replace(tmp, path)


def save(
    folder: Path,
    step: int,
    model: torch.nn.Module,
    opt: torch.optim.Optimizer | None,
    meta: dict,
    final: bool = False,
    ema: torch.nn.Module | None = None,
    keep: int = KEEP,
) -> Path:
    """Write step-<step>.{safetensors,json[,optim.safetensors][,ema.safetensors]} and point `last` at it;
    returns the JSON. `weights` are the trained model's (what --resume continues), `weights_ema` its
    moving average (what load_policy gives by default). keep: periodic checkpoints kept, 0 = all."""
    folder.mkdir(parents=True, exist_ok=True)
    stem = folder / f"step-{step:07d}"
    extra = _write_weights(stem, model, ema)
    if opt is not None:
        _write_atomic(Path(f"{stem}.optim.safetensors"), lambda p: save_file(_optim_tensors(opt), str(p)))
    meta = dict(meta, format=FORMAT, step=step, final=final, **extra)
    _write_atomic(stem.with_suffix(".json"), lambda p: p.write_text(json.dumps(meta, indent=1)))
    _write_atomic(folder / "last", lambda p: p.write_text(stem.name + "\n"))
    periodic = sorted(p for p in folder.glob("step-*.json") if not json.loads(p.read_text()).get("final"))
    for old in periodic[:-keep] if keep > 0 else []:
        for suffix in (".json", ".safetensors", ".optim.safetensors", ".ema.safetensors"):
            Path(str(old.with_suffix("")) + suffix).unlink(missing_ok=True)
    return stem.with_suffix(".json")


def _write_weights(stem: Path, model: torch.nn.Module, ema: torch.nn.Module | None) -> dict:
    """STEM.safetensors (and STEM.ema.safetensors): the meta entries naming them."""
    def state(m):
        return {k: v.detach().float().cpu().contiguous() for k, v in m.state_dict().items()}

    sd = state(model)
    _write_atomic(stem.with_suffix(".safetensors"), lambda p: save_file(sd, str(p)))
    out = {"weights": stem.with_suffix(".safetensors").name}
    if ema is not None:
        sd_ema = state(ema)
        _write_atomic(Path(f"{stem}.ema.safetensors"), lambda p: save_file(sd_ema, str(p)))
        out["weights_ema"] = f"{stem.name}.ema.safetensors"
    return out


def save_kept(folder: Path, step: int, model: torch.nn.Module, meta: dict,
              ema: torch.nn.Module | None = None) -> Path:
    """The checkpoint a run keeps for use when that is not its last (--keep val-min): valmin-<step>.*
    (weights, EMA, meta with its metrics; no optimiser: --resume continues from `last`), `kept` pointing at
    it (written after it), the one it replaces removed after that. Returns the JSON."""
    folder.mkdir(parents=True, exist_ok=True)
    stem = folder / f"valmin-{step:07d}"
    weights = _write_weights(stem, model, ema)
    meta = dict(meta, format=FORMAT, step=step, final=False, kept="val-min", **weights)
    _write_atomic(stem.with_suffix(".json"), lambda p: p.write_text(json.dumps(meta, indent=1)))
    _write_atomic(folder / "kept", lambda p: p.write_text(stem.name + "\n"))
    for old in folder.glob("valmin-*.json"):
        if old != stem.with_suffix(".json"):
            for suffix in (".json", ".safetensors", ".ema.safetensors"):
                Path(str(old.with_suffix("")) + suffix).unlink(missing_ok=True)
    return stem.with_suffix(".json")


def _valmin(run: Path) -> Path | None:
    p = Path(run) / "checkpoints" / "kept"
    j = p.parent / (p.read_text().strip() + ".json") if p.is_file() else None
    return j if j is not None and j.is_file() else None


def kept_checkpoint(run: Path) -> Path | None:
    """The JSON of the checkpoint RUN keeps for use: the one `kept` names (--keep val-min), else the last."""
    return _valmin(run) or last_checkpoint(run)


def kept_loss(run: Path, key: str = "val/loss") -> float:
    """The validation loss of RUN's val-min checkpoint (inf without one): what a resumed run must beat."""
    j = _valmin(run)
    return float("inf") if j is None else float(json.loads(j.read_text()).get("metrics", {}).get(key, "inf"))


def last_checkpoint(run: Path) -> Path | None:
    """The JSON of RUN's newest complete checkpoint, or None."""
    p = Path(run) / "checkpoints" / "last"
    if not p.is_file():
        return None
    j = p.parent / (p.read_text().strip() + ".json")
    return j if j.is_file() else None


def read_meta(path: Path) -> dict:
    p = Path(path)
    if p.is_dir():  # the checkpoint the run keeps for use (its last unless trained with --keep val-min)
        p = kept_checkpoint(p) or p / "checkpoints" / "last.json"
    if p.suffix != ".json":
        p = p.with_suffix(".json")
    if not p.is_file():
        raise UserError(
            "no policy checkpoint here", where=str(path), fix="pass a RUN folder or a step-*.json"
        )
    try:
        meta = json.loads(p.read_text())
        if meta.get("format") != FORMAT:
            raise ValueError(f"format {meta.get('format')!r}")
    except ValueError as e:
        raise ConfigError(
            f"not a policy checkpoint ({e})", where=str(p), fix="pass a factr2 train checkpoint"
        ) from None
    meta["_path"] = str(p)
    return meta


def load_policy(path, ema: bool = True) -> tuple[torch.nn.Module, dict, Preprocess]:
    """(model in eval mode, checkpoint JSON, Preprocess) from a RUN folder or a step-*.json. ema: the moving
    average of the weights where the checkpoint has one (meta["weights_used"] says which were loaded)."""
    meta = read_meta(Path(path))
    cfg = PolicyConfig.from_dict(meta["policy"])
    cfg.backbone_weights = ""  # the checkpoint's weights include the backbone
    model = make_policy(cfg)
    key = "weights_ema" if ema and meta.get("weights_ema") else "weights"
    meta["weights_used"] = "ema" if key == "weights_ema" else "trained"
    weights = Path(meta["_path"]).with_name(meta[key])
    try:
        model.load_state_dict(load_file(str(weights)))
    except (OSError, RuntimeError) as e:
        raise ConfigError(
            f"weights do not load ({type(e).__name__}: {str(e)[:80]})",
            where=str(weights),
            fix="the checkpoint is damaged: use an earlier step-*.json",
        ) from None
    return model.eval(), meta, Preprocess.from_meta(meta)


def load_optimizer(opt: torch.optim.Optimizer, json_path: Path) -> None:
    """Restore AdamW moments saved beside a checkpoint (same parameter order)."""
    t = load_file(str(Path(json_path).with_suffix("")) + ".optim.safetensors")
    sd = opt.state_dict()
    state: dict = {}
    for key, v in t.items():
        pid, name = key.split(".", 1)
        state.setdefault(int(pid), {})[name] = v
    sd["state"] = state
    opt.load_state_dict(sd)
