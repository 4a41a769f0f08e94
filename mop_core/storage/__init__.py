"""Where files go and how they are written: the layout of data/ and results/, atomic writes,
checkpoints, timing records."""
