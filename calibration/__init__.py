"""Free-motion trajectories, NEXT (data, model, training, streaming estimator), baselines, identification."""
