"""Recordings -> training samples: the episodes (recordings.py), the object inputs (privileged.py), the
dataset, its frame cache, the one preprocessing and its normaliser, and the FIRST sampler."""
