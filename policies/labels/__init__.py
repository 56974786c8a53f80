"""FIRST phase labels from tau_ext (phases.py, labelling.py; an episode's tau_ext: episode_tau.py), tare on
grasp (tare.py, tare_recording.py) and the labelling flags shared by train, export and episodes
(label_flags.py)."""
