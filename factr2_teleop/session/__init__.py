"""The session layer: one way to build each activity, below the CLI, the terminal app and the demo.

- pairs.py: TeleopOptions and build_pairs (the rig's [teleop] table, the feedback mode and its estimator).
- recording.py: SessionRecording (one MCAP per session: the per-tick hook, cameras, ground truth, timing).
- teleop.py: TeleopSession (pairs + loop + hooks + recording) on a rig opened by hardware's open_rig.
- calibration.py: the NEXT calibration pipeline (collect -> split -> train -> report), one held-out policy.
"""
