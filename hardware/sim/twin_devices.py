"""A twin's devices (SIMULATED): what one simulated device is (TwinDevice), its bank's motor parameters and
its MuJoCo model (true body, scene, contacts). hardware/sim/twin.py assembles them into worlds, banks and
emulators.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from hardware.arms.true_body import BodyError, description_errors, true_body
from hardware.errors import ConfigError
from hardware.sim.actuators import ActuatorParams, Effects
from hardware.sim.mujoco_bank import MujocoBank
from hardware.sim.presets import arm_params, motor_params
from hardware.sim.tasks.base import scene_model
from hardware.sim.world import MujocoWorld

if TYPE_CHECKING:  # the rig loader uses this package (actuator names); the twin only reads a Rig
    from hardware.rigs.rig import DeviceSpec


@dataclass
class TwinDevice:
    """One simulated device: its world, bank, emulator and wire endpoint (pty path or CAN channel)."""

    spec: DeviceSpec
    world: MujocoWorld
    bank: MujocoBank
    n_arm: int  # arm joints (the bank may add the gripper after them)
    wire: str | None = None  # the kind's wire: "serial" | "can" | None
    emulator: object | None = None
    bus: object | None = None
    endpoint: str | None = None
    body_error: BodyError | None = None  # how the simulated arm differs from its description (None: exact)


def twin_effects(spec: dict[str, bool]) -> Effects:
    """The rig's [twin] effects switches (name -> on) over the defaults."""
    return replace(Effects(), **spec)


def device_params(dev: DeviceSpec, drive, arm, with_gripper: bool, effects: Effects) -> ActuatorParams:
    """Motor parameters of a device's bank: the rig's [twin] motors, else its kind's (drive: TwinDrive),
    else the arm's presets; then the gripper motor and the rig's parameter overrides."""
    motors, gripper = dev.twin_motors or drive.motors, drive.gripper_motor
    p = arm_params(dev.arm, effects=effects, n=arm.n_joints, motors=motors)
    if with_gripper:
        g = motor_params([gripper], where=f"twin gripper of {dev.name}")
        kw = {f: np.concatenate([getattr(p, f), getattr(g, f)]) for f in ActuatorParams.ARRAY_FIELDS}
        p = replace(p, **kw)
    n = arm.n_joints + int(with_gripper)
    p = p.sized(n)
    for k, v in dev.twin_params.items():
        a = np.asarray(v, dtype=float).reshape(-1)
        if a.size not in (1, arm.n_joints, n):
            raise ConfigError(f"{k} has {a.size} values", where=f"rig {dev.name}.twin.params.{k}",
                              fix=f"give 1 or {arm.n_joints} values")
        getattr(p, k)[: a.size if a.size > 1 else n] = a
    return p


def device_model(arm, follower: bool, scene, task,
                 body_seed: int | None) -> tuple[mujoco.MjModel, BodyError | None]:
    """A device's MuJoCo model: a follower in its arm's scene (with the task's objects), a leader alone
    without contacts; on the arm's true body drawn from body_seed (None: the description exactly). The
    caller sets the timestep."""
    if follower:
        model = scene_model(arm, scene, task)
        # resting free objects sleep (no contact work until something touches them); the arm's tree is
        # actuated, so MuJoCo never puts it to sleep
        model.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    else:
        model = mujoco.MjModel.from_xml_path(str(arm.mjcf_path))  # the leader: its own world, no contacts
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    body_error = None
    # the twin's physics runs on the true body; the app keeps the description. The body comes from the
    # rig's seed, not the run's: a calibration, its held-out runs and later runs with other noise
    # seeds all meet the same unit, as on a real arm
    if body_seed is not None:
        model, body_error = true_body(model, arm, body_seed, description_errors(arm.name, arm.role))
    return model, body_error
