"""Bilateral force-feedback teleoperation: pure control laws (leader_law, feedback, mapping, soft_start),
the estimator adapters, timing statistics, the loop shell and a virtual operator for twins.

Sign convention (docs/teleop.md): tau_ext = tau_m - tau_free [N*m] on the follower joints (the paper's and the
twin's), i.e. minus the environment's torque on the follower; the leader gets tau_fb = -K_f tau_ext.
"""
