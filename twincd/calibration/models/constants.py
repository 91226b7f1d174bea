"""The calibration models' kinds and the constants their fit and score share."""

from __future__ import annotations

AFFINE = "affine"


IDENTIFIED_WHITENED = "identified-whitened"


FRICTION_WHITENED = "friction-whitened"


# ε candidates (rad/s) of the Coulomb term tanh(q̇/ε): from a near step to a soft ramp
EPSILON_GRID: tuple[float, ...] = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2)


# a joint whose residual is almost zero on training data must not get an infinite weight
MIN_SCALE = 1e-6


# Whitened models: interior edges (rad/s) of the bins of a joint's own speed |q̇_j| in which its
# residual's RMS is measured (bins 0 … len): rest, creep, slow, … fast. Chosen in
# studies/real_arm_statistics.py on the real arm's rotations and synth.
SPEED_BINS: tuple[float, ...] = (0.003, 0.01, 0.03, 0.1, 0.3)


# a bin with fewer clean training samples than this takes the joint's overall RMS
MIN_BIN_SAMPLES = 100


# the statistics a whitened model scores with: "sum" Σ_j (r_j/s_j)² (files without speed bins),
# "depth" the largest χ²_k z over the first k joints (``depth_score``)
STATISTICS = ("sum", "depth")


# ridge of the identified model's least squares, relative to each (standardised) column's own
# spread: enough to pin θ's unidentifiable combinations at zero, far below any real signal
IDENTIFIED_RIDGE = 1e-6


# the order of the per-joint coefficients in a calibration file (``ResidualModel.to_dict``):
# these first, as earlier files have them, then any other a model kind learns (``learned``)
COEFFICIENTS = ("a", "b", "c", "d", "epsilon", "scale", "theta")
