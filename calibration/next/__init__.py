"""NEXT: learned free-space inverse dynamics for sensorless external joint torque (FACTR 2, Sec. 4).

data.py (logs -> windows), model.py (LSTM/GRU/MLP), train.py (training loop), checkpoint.py (safetensors +
JSON metadata), estimator.py (streaming estimator for the control loop).
"""
