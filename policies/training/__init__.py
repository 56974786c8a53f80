"""One training run: its options (run_config.py, flags.py, methods.py), the loop (train.py) and its CPU side
(train_threads.py, cost_hint.py), checkpoints, curves, and run.py that ties them."""
