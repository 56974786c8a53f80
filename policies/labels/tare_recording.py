"""The tare's inputs from a recording (policies.labels.tare does the math): each follower's joints and gripper
on the tau_ext timeline, and the arm description's payload model (calibration.diagnosis's gravity regressor of
a point mass on the last link, and its plausibility check)."""

from __future__ import annotations

import numpy as np

from hardware.errors import ConfigError
from hardware.recording import schemas as S
from hardware.recording.reader import Episode, interp_linear
from policies.data.recordings import ArmSet
from policies.labels import tare as T


def payload_regressor(arm_model: str, joint_names) -> T.Regressor | None:
    """q (K, n) -> the gravity regressor (K, n, 4) of a point payload on the last link of the arm description
    (calibration.diagnosis.basis.payload_columns at rest); None when the recording names no description
    this project has, or its joints differ."""
    if not arm_model:
        return None
    from calibration.diagnosis.basis import payload_columns
    from hardware.arms import load_arm

    try:
        desc = load_arm(arm_model)
    except (ConfigError, OSError, ValueError):  # unknown or unreadable: the caller falls back to a bias
        return None
    if joint_names and list(desc.joint_names) != list(joint_names):
        return None
    model = desc.pinocchio_model()

    def regressor(q: np.ndarray) -> np.ndarray:  # at rest: the load's gravity (a few us per sample)
        z = np.zeros_like(q)
        return payload_columns(model, q, z, z) if len(q) else np.zeros((0, q.shape[1], 4))

    return regressor


def payload_implausible(theta: np.ndarray) -> str:
    """Why a fitted (m [kg], m*c [kg*m]) cannot be a held object (calibration.diagnosis's payload family):
    a mass that is not positive, or a centre over a metre from the flange; "" when it can."""
    from calibration.diagnosis.effects import Effect

    return Effect("payload", 0, coef=np.asarray(theta, float)).implausible()


def payload_model(arm_model: str, joint_names) -> tuple[T.Regressor, T.Plausible] | None:
    """The tare's payload model of an arm: (regressor about the gripper's centre point, the arm description's
    end-effector frame when it hangs on the last joint, else the flange; its plausibility check); None
    without a usable description."""
    reg = payload_regressor(arm_model, joint_names)
    if reg is None:
        return None
    from hardware.arms import load_arm

    desc = load_arm(arm_model)
    model = desc.pinocchio_model()
    frame = model.frames[model.getFrameId(desc.ee_site)]
    parent = frame.parentJoint if hasattr(frame, "parentJoint") else frame.parent  # pinocchio 3 / 2
    c = np.array(frame.placement.translation, float) if parent == model.njoints - 1 else np.zeros(3)
    return (lambda q: T.about_point(reg(q), c)), (lambda th: payload_implausible(T.from_point(th, c)))


def gripper_signals(ep: Episode, arm: str, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q (N, n) [rad], measured stroke (N,) [m], commanded stroke (N,) [m]) of one follower on times t; the
    command is NaN where the recording has none (no hold is seen then)."""
    js = ep.topic(S.joint_state_topic(arm))
    q = interp_linear(js.t, np.asarray(js.fields["q"], float), t)
    stroke = interp_linear(js.t, np.asarray(js.fields["gripper_pos"], float), t)
    topic = S.command_topic(arm)
    if topic in ep.recording.topics and len(ep.topic(topic)) >= 2:
        cmd = ep.topic(topic)
        command = interp_linear(cmd.t, np.asarray(cmd.fields["gripper"], float), t)
    else:
        command = np.full(len(t), np.nan)
    return q, stroke, command


def episode_tare(ep: Episode, arms: ArmSet, t: np.ndarray, tau: np.ndarray, method: str
                 ) -> tuple[np.ndarray, np.ndarray, str]:
    """(load (N, J) [N*m], held (N,) bool: any follower holds, note) for episode_tau_ext's (t, tau): each
    follower's held-object load from its own gripper and joints (policies.labels.tare). method "payload" falls
    back to "bias" for an arm whose description is unknown (the note says so); "off": zeros."""
    load, held = np.zeros_like(tau), np.zeros(len(t), bool)
    if method == "off":
        return load, held, ""
    notes, col = [], 0
    for arm, names, model in zip(arms.followers, arms.joint_names, arms.arm_models):
        n = len(names)
        q, stroke, command = gripper_signals(ep, arm, t)
        pm = payload_model(model, names) if method == "payload" else None
        if method == "payload" and pm is None:
            notes.append(f"{arm}: bias (no arm description)")
        reg, plausible = pm or (T.bias_regressor, T.always)
        res = T.held_load(t, tau[:, col:col + n], q, T.held_mask(t, stroke, command), reg, plausible)
        load[:, col:col + n] = res.load
        held |= res.held
        col += n
        if res.stretches:
            why = sorted({w for w in res.skipped if w})
            done = sum(not w for w in res.skipped)
            why = f", not: {'; '.join(why)}" if why else ""
            notes.append(f"{arm}: {done}/{len(res.skipped)} holds tared{why}")
    return load, held, "; ".join(notes)
