"""Official NEXT H5 files (schema factr2_next_h5_v1) written the way its published recorder lays them out:
root attributes schema / session_name / created_at, ep_NNNN/<key>/{data float32 (rows, joints), timestamps
int64 ns} with the same stamp for every key of a row, keys from the record config ("<arm>_joint_pos", ...).
Written here with h5py from that description, for the tests."""

from __future__ import annotations

import numpy as np

KEYS = ("joint_pos", "joint_vel", "joint_cmd", "measured_joint_torque")
RATE_HZ = 50.0  # the official record config's target_hz
T0_NS = 1_764_000_000_000_000_000  # a 2025 wall-clock stamp [ns]: float64 seconds would lose its ns


def free_motion(n: int, n_joints: int = 6, seed: int = 0, rate_hz: float = RATE_HZ):
    """(q [rad], qd [rad/s], q_cmd [rad], tau [N*m]) of n rows of smooth free motion with a known free
    torque (gravity-like, viscous and Coulomb friction)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    f = rng.uniform(0.2, 0.6, n_joints)
    ph = rng.uniform(0, 2 * np.pi, n_joints)
    q = 0.8 * np.sin(2 * np.pi * f * t[:, None] + ph)
    qd = 0.8 * 2 * np.pi * f * np.cos(2 * np.pi * f * t[:, None] + ph)
    q_cmd = q + 0.02 * qd
    tau = 2.0 * np.sin(q) + 0.5 * qd + 0.1 * np.tanh(20 * qd)
    return q, qd, q_cmd, tau


def write_next_h5(path, lengths=(600, 450), arms=("",), n_joints: int = 6, schema="factr2_next_h5_v1",
                  drop=(), short=None):
    """Episodes of `lengths` rows per arm prefix ("" = unprefixed keys); drop: keys (full names) left out of
    every episode; short: (key, rows) a key that stops early (a recorder killed mid-append)."""
    import h5py

    with h5py.File(path, "w") as h:
        if schema is not None:
            h.attrs["schema"] = schema
        h.attrs["session_name"] = "free_motion"
        h.attrs["created_at"] = "2026-11-30T12:00:00+00:00"
        stamp = T0_NS
        for e, n in enumerate(lengths):
            ep = h.create_group(f"ep_{e:04d}")
            ts = stamp + np.arange(n, dtype=np.int64) * int(1e9 / RATE_HZ)
            for a, arm in enumerate(arms):
                arrays = free_motion(n, n_joints, seed=10 * e + a)
                for key, data in zip(KEYS, arrays):
                    name = f"{arm}_{key}" if arm else key
                    if name in drop:
                        continue
                    rows = short[1] if short and short[0] == name else n
                    g = ep.create_group(name)
                    g["data"] = data[:rows].astype(np.float32)
                    g["timestamps"] = ts[:rows]
            stamp = int(ts[-1]) + 2_000_000_000
    return path
