"""NEXT checkpoints in the official stack's layout (the paper's ROS 2 `factr2_next`), both ways.

The official run folder (read from its published trainer and loader):

    model.pt            torch.save of {"model_state_dict", "input_size", "output_size", "history", "model"}:
                        an LSTM (batch_first; "lstm.*") on the window, then head Linear(hidden, head_hidden)
                        - ReLU [- Dropout when dropout > 0] - Linear(head_hidden, joints) on the last step
    normalization.npz   x_mean, x_std (per input feature, over samples and window steps; std + 1e-6),
                        y_mean, y_std (per joint)
    metrics.json        {"arm", "train_loss": [...], "val_loss": [...]}
    config.yaml         the training config (data keys, history, model sizes)

Inputs per step: (joint_pos [rad], joint_vel [rad/s], joint_cmd - joint_pos [rad]) = factr2's "q,qd,dq";
output: the free-space torque [N*m]; tau_ext = measured - predicted, the sign used here too. That is
factr2's NextModel with arch "lstm", no physics prior and no gate, so an official checkpoint loads as one
(keys renamed, the head's last layer at index 3) and ours can be written as one: a gate (tau = g * head +
offset per joint, calibration.next.gate) is folded into the head's last layer, exactly. A checkpoint with a
physics prior, another architecture or other inputs cannot be: one line says why.

The official files carry no sample rate, joint names or units: loading assumes the official recorder's
50 Hz (record config target_hz), joint1..n and N*m unless a `factr2` entry (written by write_official) in
config.yaml says otherwise. config.yaml is written as JSON, which YAML readers read as it is.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from calibration.next.data import Normalizer
from calibration.next.model import ModelConfig, NextModel
from hardware.errors import ConfigError

if TYPE_CHECKING:  # checkpoint.load_checkpoint reads official folders through read_official
    from calibration.next.checkpoint import NextCheckpoint

OFFICIAL_RATE_HZ = 50.0  # [Hz] the official recorder's target_hz: what its checkpoints were trained at
FILES = ("model.pt", "normalization.npz")
FIX = "pass the official run folder (model.pt, normalization.npz, metrics.json, config.yaml)"


def is_official(path: str | Path) -> bool:
    p = Path(path)
    return p.is_dir() and all((p / f).is_file() for f in FILES)


def _bad(path, why: str, fix: str = FIX) -> ConfigError:
    return ConfigError(f"cannot load the official NEXT checkpoint: {why}", where=str(path), fix=fix)


def _read_config(d: Path) -> dict:
    p = d / "config.yaml"
    if not p.is_file():
        return {}
    text = p.read_text()
    try:
        return json.loads(text)
    except ValueError:
        pass
    try:
        import yaml

        return yaml.safe_load(text) or {}
    except ImportError:
        return {}
    except Exception:  # noqa: BLE001 -- a damaged config is not needed to run the model
        return {}


def read_official(path: str | Path) -> dict:
    """The official run folder as the fields of a factr2 NextCheckpoint (module docstring; load_checkpoint
    builds it), or one ConfigError why not."""
    d = Path(path)
    missing = [f for f in FILES if not (d / f).is_file()]
    if missing:
        raise _bad(d, f"missing {', '.join(missing)}")
    try:
        ck = torch.load(d / "model.pt", map_location="cpu", weights_only=True)
        sd = ck["model_state_dict"]
        n_in, n_out, history = int(ck["input_size"]), int(ck["output_size"]), int(ck["history"])
        mcfg = dict(ck.get("model") or {})
    except Exception as e:  # noqa: BLE001 -- torch.load raises many kinds on a foreign file: one line
        raise _bad(d, f"model.pt ({type(e).__name__}: {str(e)[:60]})") from None
    cfg_file = _read_config(d)
    mcfg = {**(cfg_file.get("model") or {}), **mcfg}
    if str(mcfg.get("type", "lstm")) != "lstm" or "lstm.weight_ih_l0" not in sd:
        raise _bad(d, f"model type {mcfg.get('type', '?')!r}: only the official LSTM regressor has a "
                   "factr2 equivalent")
    if n_in != 3 * n_out:
        raise _bad(d, f"input_size {n_in} is not 3 x output_size {n_out}: not the (pos, vel, cmd - pos) "
                   "inputs")
    layers = sum(1 for k in sd if k.startswith("lstm.weight_ih_l"))
    hidden = int(sd["lstm.weight_hh_l0"].shape[1])
    heads = sorted(int(k.split(".")[1]) for k in sd if k.startswith("head.") and k.endswith(".weight"))
    if len(heads) != 2:
        raise _bad(d, f"a head of {len(heads)} linear layers (the official head has 2)")
    head_hidden = int(sd[f"head.{heads[0]}.weight"].shape[0])
    cfg = ModelConfig(n_in=n_in, n_out=n_out, history=history, arch="lstm", hidden=hidden, layers=layers,
                      head_hidden=head_hidden, dropout=float(mcfg.get("dropout", 0.0)))
    model = NextModel(cfg)
    ours = {("rnn." + k[len("lstm."):]) if k.startswith("lstm.") else k: v for k, v in sd.items()}
    for part in ("weight", "bias"):  # the head's last layer: index 2 or 3 there, 3 here
        ours[f"head.3.{part}"] = ours.pop(f"head.{heads[1]}.{part}")
    try:
        model.load_state_dict(ours)
        with np.load(d / "normalization.npz") as z:
            norm = Normalizer(*(np.asarray(z[k], np.float64).reshape(-1) for k in ("x_mean", "x_std",
                                                                                  "y_mean", "y_std")))
    except (RuntimeError, KeyError, ValueError, OSError) as e:
        raise _bad(d, f"{type(e).__name__}: {str(e)[:80]}") from None
    if norm.x_mean.shape != (n_in,) or norm.y_mean.shape != (n_out,):
        raise _bad(d, f"normalization.npz sizes {norm.x_mean.shape}, {norm.y_mean.shape} for {n_in} inputs "
                   f"and {n_out} outputs")
    model.eval()
    own = cfg_file.get("factr2") or {}
    metrics = _read_metrics(d)
    return dict(
        model=model, normalizer=norm, arm=str(own.get("arm", "")),
        joint_names=list(own.get("joint_names") or [f"joint{i + 1}" for i in range(n_out)]),
        units=str(own.get("units", "N*m")), inputs="q,qd,dq",
        rate_hz=float(own.get("rate_hz", OFFICIAL_RATE_HZ)),
        x_min=np.asarray(own.get("x_min", np.full(n_in, -np.inf)), float),
        x_max=np.asarray(own.get("x_max", np.full(n_in, np.inf)), float),
        data_hash=str(own.get("data_hash", "")), train_config={"official": cfg_file},
        metrics=metrics.get("factr2") or {"official": metrics}, prior=None)


def _read_metrics(d: Path) -> dict:
    try:
        m = json.loads((d / "metrics.json").read_text())
        return m if isinstance(m, dict) else {}
    except (OSError, ValueError):
        return {}


def official_state(ck: NextCheckpoint) -> dict[str, torch.Tensor]:
    """Our weights under the official names, the gate folded into the head's last layer; ConfigError when the
    checkpoint has no official equivalent."""
    c = ck.model.cfg
    why = ("it has a physics prior (calibrate with --prior none)" if ck.prior is not None
           else f"its architecture is {c.arch} (the official model is the LSTM)" if c.arch != "lstm"
           else f"its inputs are {ck.inputs} (the official ones are q,qd,dq)" if ck.inputs != "q,qd,dq"
           else "")
    if why:
        raise ConfigError(f"this NEXT checkpoint has no official layout: {why}", where="",
                          fix="calibrate with --prior none --arch lstm --inputs q,qd,dq")
    sd = {k: v.detach().cpu().clone() for k, v in ck.model.state_dict().items()}
    out = {("lstm." + k[len("rnn."):]) if k.startswith("rnn.") else k: v for k, v in sd.items()
           if not k.startswith("head.3.")}
    w, b = sd["head.3.weight"].double(), sd["head.3.bias"].double()
    if c.gate is not None:  # out = g * (W h + b) + o  ->  W' = diag(g) W, b' = g b + o
        g, o = torch.tensor(c.gate, dtype=torch.float64), torch.tensor(c.gate_offset, dtype=torch.float64)
        w, b = g[:, None] * w, g * b + o
    last = 3 if c.dropout > 0 else 2  # the official head has a Dropout at index 2 only when dropout > 0
    out[f"head.{last}.weight"], out[f"head.{last}.bias"] = w.float(), b.float()
    return out


def write_official(ck: NextCheckpoint, out: str | Path) -> Path:
    """Write `ck` as an official run folder `out` (must not exist yet, or be empty)."""
    out = Path(out)
    sd = official_state(ck)
    if out.exists() and any(out.iterdir()):
        raise ConfigError("output folder is not empty", where=str(out), fix="name a new folder")
    out.mkdir(parents=True, exist_ok=True)
    c = ck.model.cfg
    model_cfg = {"type": "lstm", "hidden_size": c.hidden, "num_layers": c.layers,
                 "head_hidden": c.head_hidden, "dropout": c.dropout}
    torch.save({"model_state_dict": sd, "input_size": c.n_in, "output_size": c.n_out, "history": c.history,
                "model": model_cfg}, out / "model.pt")
    n = ck.normalizer
    np.savez(out / "normalization.npz", x_mean=n.x_mean, x_std=n.x_std, y_mean=n.y_mean, y_std=n.y_std)
    (out / "metrics.json").write_text(json.dumps({"arm": ck.arm or None, "train_loss": [], "val_loss": [],
                                                  "factr2": ck.metrics or {}}, indent=2))
    keys = {k: "{arm}_" + k for k in ("joint_pos", "joint_vel", "joint_cmd", "measured_joint_torque")}
    config = {"data": {"history": c.history, "keys": keys},
              "model": model_cfg,
              "next": {"sign_convention": "measured_minus_predicted"},
              "factr2": {"arm": ck.arm, "joint_names": list(ck.joint_names), "units": ck.units,
                         "rate_hz": ck.rate_hz, "data_hash": ck.data_hash,
                         "x_min": np.asarray(ck.x_min, float).tolist(),
                         "x_max": np.asarray(ck.x_max, float).tolist()}}
    (out / "config.yaml").write_text(json.dumps(config, indent=2))
    return out
