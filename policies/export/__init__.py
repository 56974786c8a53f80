"""Training data out to other tools: a LeRobotDataset v3 folder and its videos."""
