"""Rigid-body dynamics of an arm description (pinocchio), numpy in / numpy out.

Units: q [rad], qd [rad/s], qdd [rad/s^2], torques [N*m]; arrays are (n,) for one sample and (T, n) for
batches; joint order = ArmDescription.joint_names. The model is the arm without its gripper joints (locked
closed) and WITH the joints' armature: mass_matrix = M_rigid + diag(armature) (as MuJoCo's qM) and
rnea = M qdd + C qd + g with that M. No friction or damping (MuJoCo's passive forces) anywhere here.

Two ways to call:
    dyn = ArmDynamics(load_arm("piper"))     # owns a pinocchio Data: fast, one per thread
    tau = dyn.rnea(q, qd, qdd)
    g = gravity("piper", q)                  # module functions: a cached ArmDynamics per thread

Batched versions loop over rows in a tight loop reusing one Data (pinocchio has no batched RNEA in
Python); they write into preallocated arrays.

Regressor layout (system identification): regressor(q, qd, qdd) @ parameters() == rnea(q, qd, qdd).
Columns: 10 per arm link (pinocchio's order: m, m*c_x, m*c_y, m*c_z, Ixx, Ixy, Iyy, Ixz, Iyz, Izz, inertia
about the joint frame origin, in the joint frame), then one armature column per joint (= qdd_i) unless
armature=False. friction_regressor(qd) gives [diag(qd), diag(sign(qd))] columns for viscous/Coulomb terms.
"""

from __future__ import annotations

import threading

import numpy as np
import pinocchio as pin

from hardware.arms import ArmDescription, load_arm

_LOCAL = threading.local()
WORLD = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class ArmDynamics:
    """pinocchio model + reusable Data for one arm. Not thread-safe: one instance per thread."""

    def __init__(self, arm: ArmDescription | str):
        self.arm = arm if isinstance(arm, ArmDescription) else load_arm(arm)
        self.model = self.arm.pinocchio_model()
        self.data = self.model.createData()
        self.n = self.model.nv
        self.ee_frame = self.model.getFrameId(self.arm.ee_site)
        self.armature = np.array(self.model.armature, dtype=float)
        self._lower = np.tril_indices(self.n, -1)  # crba fills the upper triangle only
        # the same entries as flat indices of an (n, n) C-ordered matrix: one gather and one scatter per
        # mass_matrix (the loop's observer calls it at the follower's rate), the same values
        self._lower_flat = np.ravel_multi_index(self._lower, (self.n, self.n))
        self._upper_flat = np.ravel_multi_index(self._lower[::-1], (self.n, self.n))

    # -- helpers -----------------------------------------------------------------------------------
    def _vec(self, x, name: str) -> np.ndarray:
        a = np.asarray(x, dtype=float)
        if a.shape != (self.n,):
            raise ValueError(f"{name} must have shape ({self.n},), got {a.shape}")
        return a

    def _mat(self, x, name: str) -> np.ndarray:
        a = np.asarray(x, dtype=float)
        if a.ndim != 2 or a.shape[1] != self.n:
            raise ValueError(f"{name} must have shape (T, {self.n}), got {a.shape}")
        return a

    # -- single samples ----------------------------------------------------------------------------
    def gravity(self, q) -> np.ndarray:
        """g(q) [N*m]: joint torques that hold the arm still against gravity."""
        return pin.computeGeneralizedGravity(self.model, self.data, self._vec(q, "q")).copy()

    def gravity_floats(self, q) -> list[float]:
        """gravity(q).tolist() without the copy (the leader law's 500 Hz term, LeaderLaw.gravity_floats)."""
        return pin.computeGeneralizedGravity(self.model, self.data, self._vec(q, "q")).tolist()

    def rnea(self, q, qd, qdd) -> np.ndarray:
        """Inverse dynamics tau = M(q) qdd + C(q, qd) qd + g(q) [N*m] (M includes armature)."""
        return pin.rnea(self.model, self.data, self._vec(q, "q"), self._vec(qd, "qd"),
                        self._vec(qdd, "qdd")).copy()

    def mass_matrix(self, q) -> np.ndarray:
        """M(q) [kg*m^2] (n, n), symmetric, armature on the diagonal."""
        m = np.array(pin.crba(self.model, self.data, self._vec(q, "q")), order="C")
        f = m.reshape(-1)  # a view of m
        f[self._lower_flat] = f[self._upper_flat]
        return m

    def coriolis_matrix(self, q, qd) -> np.ndarray:
        """C(q, qd) (n, n) with C qd = Coriolis + centrifugal torques and dM/dt - 2C skew-symmetric."""
        return pin.computeCoriolisMatrix(self.model, self.data, self._vec(q, "q"), self._vec(qd, "qd")).copy()

    def nonlinear_effects(self, q, qd) -> np.ndarray:
        """C(q, qd) qd + g(q) [N*m]."""
        return pin.nonLinearEffects(self.model, self.data, self._vec(q, "q"), self._vec(qd, "qd")).copy()

    def regressor(self, q, qd, qdd, armature: bool = True) -> np.ndarray:
        """Y(q, qd, qdd) with Y @ parameters(armature) == rnea(q, qd, qdd); (n, 10 n [+ n])."""
        q, qd, qdd = self._vec(q, "q"), self._vec(qd, "qd"), self._vec(qdd, "qdd")
        y = pin.computeJointTorqueRegressor(self.model, self.data, q, qd, qdd)
        return np.hstack([y, np.diag(qdd)]) if armature else y.copy()

    def parameters(self, armature: bool = True) -> np.ndarray:
        """Dynamic parameters of the model in regressor column order (10 per link [+ armature])."""
        p = [self.model.inertias[j].toDynamicParameters() for j in range(1, self.model.njoints)]
        if armature:
            p.append(self.armature)
        return np.concatenate(p)

    @staticmethod
    def friction_regressor(qd) -> np.ndarray:
        """[diag(qd), diag(sign(qd))] (n, 2n): viscous [N*m*s/rad] and Coulomb [N*m] friction columns."""
        v = np.asarray(qd, dtype=float)
        return np.hstack([np.diag(v), np.diag(np.sign(v))])

    def fk(self, q) -> np.ndarray:
        """End-effector site pose in the arm base (world) frame: 4x4 homogeneous transform [m]."""
        pin.framesForwardKinematics(self.model, self.data, self._vec(q, "q"))
        return self.data.oMf[self.ee_frame].homogeneous.copy()

    def jacobian(self, q) -> np.ndarray:
        """End-effector Jacobian (6, n): rows (vx, vy, vz, wx, wy, wz) in base-aligned axes at the site."""
        return pin.computeFrameJacobian(self.model, self.data, self._vec(q, "q"), self.ee_frame, WORLD).copy()

    # -- batches (T, n) ----------------------------------------------------------------------------
    def gravity_batch(self, Q) -> np.ndarray:
        Q = self._mat(Q, "Q")
        out = np.empty_like(Q)
        model, data, f = self.model, self.data, pin.computeGeneralizedGravity
        for t in range(Q.shape[0]):
            out[t] = f(model, data, Q[t])
        return out

    def rnea_batch(self, Q, QD, QDD) -> np.ndarray:
        Q, QD, QDD = self._mat(Q, "Q"), self._mat(QD, "QD"), self._mat(QDD, "QDD")
        if not (Q.shape == QD.shape == QDD.shape):
            raise ValueError(f"Q, QD, QDD shapes differ: {Q.shape}, {QD.shape}, {QDD.shape}")
        out = np.empty_like(Q)
        model, data, f = self.model, self.data, pin.rnea
        for t in range(Q.shape[0]):
            out[t] = f(model, data, Q[t], QD[t], QDD[t])
        return out

    def nonlinear_effects_batch(self, Q, QD) -> np.ndarray:
        Q, QD = self._mat(Q, "Q"), self._mat(QD, "QD")
        if Q.shape != QD.shape:
            raise ValueError(f"Q and QD shapes differ: {Q.shape}, {QD.shape}")
        out = np.empty_like(Q)
        model, data, f = self.model, self.data, pin.nonLinearEffects
        for t in range(Q.shape[0]):
            out[t] = f(model, data, Q[t], QD[t])
        return out

    def mass_matrix_batch(self, Q) -> np.ndarray:
        Q = self._mat(Q, "Q")
        out = np.empty((Q.shape[0], self.n, self.n))
        model, data = self.model, self.data
        for t in range(Q.shape[0]):
            out[t] = pin.crba(model, data, Q[t])
        lo_r, lo_c = self._lower
        out[:, lo_r, lo_c] = out[:, lo_c, lo_r]
        return out

    def coriolis_matrix_batch(self, Q, QD) -> np.ndarray:
        Q, QD = self._mat(Q, "Q"), self._mat(QD, "QD")
        out = np.empty((Q.shape[0], self.n, self.n))
        model, data = self.model, self.data
        for t in range(Q.shape[0]):
            out[t] = pin.computeCoriolisMatrix(model, data, Q[t], QD[t])
        return out

    def regressor_batch(self, Q, QD, QDD, armature: bool = True) -> np.ndarray:
        """(T, n, 10 n [+ n]) regressors; stack rows with .reshape(-1, P) for least squares."""
        Q, QD, QDD = self._mat(Q, "Q"), self._mat(QD, "QD"), self._mat(QDD, "QDD")
        n, p = self.n, 10 * (self.model.njoints - 1)
        out = np.zeros((Q.shape[0], n, p + (n if armature else 0)))
        model, data, f = self.model, self.data, pin.computeJointTorqueRegressor
        idx = np.arange(n)
        for t in range(Q.shape[0]):
            out[t, :, :p] = f(model, data, Q[t], QD[t], QDD[t])
        if armature:
            out[:, idx, p + idx] = QDD
        return out

    def fk_batch(self, Q) -> np.ndarray:
        Q = self._mat(Q, "Q")
        out = np.empty((Q.shape[0], 4, 4))
        model, data, fid = self.model, self.data, self.ee_frame
        for t in range(Q.shape[0]):
            pin.framesForwardKinematics(model, data, Q[t])
            out[t] = data.oMf[fid].homogeneous
        return out

    def jacobian_batch(self, Q) -> np.ndarray:
        Q = self._mat(Q, "Q")
        out = np.empty((Q.shape[0], 6, self.n))
        model, data, fid = self.model, self.data, self.ee_frame
        for t in range(Q.shape[0]):
            out[t] = pin.computeFrameJacobian(model, data, Q[t], fid, WORLD)
        return out


def dynamics_for(arm: ArmDescription | str) -> ArmDynamics:
    """The calling thread's cached ArmDynamics for `arm` (keyed by the file's sha256)."""
    desc = arm if isinstance(arm, ArmDescription) else load_arm(arm)
    cache = getattr(_LOCAL, "cache", None)
    if cache is None:
        cache = _LOCAL.cache = {}
    key = (str(desc.mjcf_path), desc.sha256)
    if key not in cache:
        cache[key] = ArmDynamics(desc)
    return cache[key]


def gravity(arm, q) -> np.ndarray:
    return dynamics_for(arm).gravity(q)


def rnea(arm, q, qd, qdd) -> np.ndarray:
    return dynamics_for(arm).rnea(q, qd, qdd)


def mass_matrix(arm, q) -> np.ndarray:
    return dynamics_for(arm).mass_matrix(q)


def coriolis_matrix(arm, q, qd) -> np.ndarray:
    return dynamics_for(arm).coriolis_matrix(q, qd)


def nonlinear_effects(arm, q, qd) -> np.ndarray:
    return dynamics_for(arm).nonlinear_effects(q, qd)


def regressor(arm, q, qd, qdd, armature: bool = True) -> np.ndarray:
    return dynamics_for(arm).regressor(q, qd, qdd, armature)


def fk(arm, q) -> np.ndarray:
    return dynamics_for(arm).fk(q)


def jacobian(arm, q) -> np.ndarray:
    return dynamics_for(arm).jacobian(q)
