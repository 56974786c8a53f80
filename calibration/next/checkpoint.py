"""NEXT checkpoints: weights in `<stem>.safetensors` (no pickle), everything else in `<stem>.json`:
arm, joint names, units, data hash, normalisation, training input range (OOD flag), model + train config,
metrics, and the physics prior the network was trained on top of (calibration.next.prior; null = none).
Loading a checkpoint for another arm or joint set is refused with a UserError.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from calibration.next.data import Normalizer
from calibration.next.model import ModelConfig, NextModel
from calibration.next.prior_base import TorquePrior
from calibration.next.priors import prior_from_dict
from hardware.errors import ConfigError, UserError

FORMAT = "factr2-next/1"


@dataclass
class NextCheckpoint:
    model: NextModel
    normalizer: Normalizer
    arm: str
    joint_names: list[str]
    units: str  # "N*m" or "A": the torque signal the model predicts
    inputs: str
    rate_hz: float
    x_min: np.ndarray  # raw training input range [rad, rad/s, rad]
    x_max: np.ndarray
    data_hash: str = ""
    train_config: dict | None = None
    metrics: dict | None = None
    prior: TorquePrior | None = None  # any kind (calibration.next.priors); tau_f = prior + network

    @property
    def history(self) -> int:
        return self.model.cfg.history


def _paths(path: str | Path) -> tuple[Path, Path]:
    p = Path(path)
    if p.suffix in (".json", ".safetensors"):
        p = p.with_suffix("")
    return p.with_suffix(".safetensors"), p.with_suffix(".json")


def save_checkpoint(ck: NextCheckpoint, path: str | Path) -> Path:
    """Write <path>.safetensors and <path>.json; returns the JSON path."""
    w_path, j_path = _paths(path)
    w_path.parent.mkdir(parents=True, exist_ok=True)
    save_file({k: v.detach().cpu().contiguous() for k, v in ck.model.state_dict().items()}, str(w_path))
    meta = {"format": FORMAT, "arm": ck.arm, "joint_names": list(ck.joint_names), "units": ck.units,
            "inputs": ck.inputs, "rate_hz": ck.rate_hz, "data_hash": ck.data_hash,
            "model": ck.model.cfg.to_dict(), "normalization": ck.normalizer.to_dict(),
            "input_range": {"min": np.asarray(ck.x_min).tolist(), "max": np.asarray(ck.x_max).tolist()},
            "train_config": ck.train_config or {}, "metrics": ck.metrics or {},
            "prior": ck.prior.to_dict() if ck.prior is not None else None, "weights": w_path.name}
    j_path.write_text(json.dumps(meta, indent=1))
    return j_path


def load_checkpoint(path: str | Path, arm: str | None = None, joint_names: list[str] | None = None
                    ) -> NextCheckpoint:
    """Load a checkpoint; with `arm` / `joint_names` given, refuse one trained for anything else. A folder in
    the official stack's layout (model.pt, normalization.npz: calibration.next.official) loads too; it names
    no joints unless written here, so only their number is checked then."""
    if Path(path).is_dir():
        from calibration.next.official import read_official

        ck = NextCheckpoint(**read_official(path))
        if joint_names is not None and len(joint_names) != len(ck.joint_names):
            raise UserError(f"official NEXT checkpoint for {len(ck.joint_names)} joints, this arm has "
                            f"{len(joint_names)}", where=str(path), fix="use the checkpoint of this arm")
        return ck
    w_path, j_path = _paths(path)
    for p in (j_path, w_path):
        if not p.exists():
            raise UserError("NEXT checkpoint file not found", where=str(p),
                            fix="run `factr2 calibrate` to train one, or pass the right --checkpoint path")
    try:
        meta = json.loads(j_path.read_text())
        if meta.get("format") != FORMAT:
            raise ValueError(f"format {meta.get('format')!r}")
        cfg = ModelConfig(**meta["model"])
        model = NextModel(cfg)
        model.load_state_dict(load_file(str(w_path)))
        prior = prior_from_dict(meta["prior"], len(meta["joint_names"])) if meta.get("prior") else None
    except (ValueError, KeyError, TypeError, RuntimeError, OSError) as e:
        raise ConfigError(f"not a readable NEXT checkpoint ({type(e).__name__}: {str(e)[:80]})",
                          where=str(j_path), fix="retrain with `factr2 calibrate`") from None
    model.eval()
    if arm is not None and meta["arm"] and arm != meta["arm"]:
        raise UserError(f"checkpoint was trained for arm {meta['arm']!r}, not {arm!r}", where=str(j_path),
                        fix=f"run `factr2 calibrate` on the {arm} to train its own NEXT model")
    if joint_names is not None and list(joint_names) != list(meta["joint_names"]):
        raise UserError(f"checkpoint joints {meta['joint_names']} differ from this arm's "
                        f"{list(joint_names)}", where=str(j_path),
                        fix="use a checkpoint trained on this arm's joints (factr2 calibrate)")
    return NextCheckpoint(model=model, normalizer=Normalizer.from_dict(meta["normalization"]),
                          arm=meta["arm"], joint_names=meta["joint_names"], units=meta["units"],
                          inputs=meta["inputs"],
                          rate_hz=float(meta["rate_hz"]), x_min=np.asarray(meta["input_range"]["min"]),
                          x_max=np.asarray(meta["input_range"]["max"]), data_hash=meta.get("data_hash", ""),
                          train_config=meta.get("train_config"), metrics=meta.get("metrics"), prior=prior)


def weights_numpy(model: NextModel) -> dict[str, np.ndarray]:
    """State dict as float32 numpy arrays (for the numpy streaming estimator)."""
    with torch.no_grad():
        return {k: v.detach().cpu().numpy().astype(np.float32) for k, v in model.state_dict().items()}
