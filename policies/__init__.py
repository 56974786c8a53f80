"""FIRST phase labels and re-sampling, ACT and flow-matching policies, training (one process or DDP), and
the LeRobot export: docs/first.md, docs/policies.md."""
