"""The digital twin: robot models (Pinocchio, example-robot-data) and inverse dynamics."""

import os

# Pinocchio's batched RNEA runs on OpenMP, whose threads by default spin for a while after each
# parallel region, burning the core that reading and filtering need between two twin calls:
# passive waiting made detect 15 % faster (benchmarks/bench_long.py). Set before Pinocchio is
# first imported; a value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
