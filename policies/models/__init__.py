"""The policies: the base class and registry (policy.py), the one config and its presets (config.py), ACT,
flow matching (DiT and the state preset's MLP), the image encoders and the observation tokens."""
