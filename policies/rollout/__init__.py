"""A trained policy at rollout, torch-side: chunk scheduling as pure functions (schedule.py: ACT temporal
ensembling, flow receding horizon, interpolation to the loop rate, the executed action's age) and the
PolicyRunner (runner.py: checkpoint -> model input by feature name -> chunk, inline or on its own thread).
The rig side is factr2_teleop/session/rollout.py."""
