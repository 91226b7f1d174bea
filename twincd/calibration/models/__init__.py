"""The calibration models (contract: The calibration file ``model``): one class per kind with
one interface (``ResidualModel``: ``stats`` → ``merge`` → ``solve``, then ``predict``,
``residual`` and ``score``), the mergeable statistics they fit from, and their scores.

- ``affine``: τ̃ ≈ a⊙τ̂̃ + b, score ‖r‖² (the seed paper, eq. 3–5).
- ``friction``: per joint τ̃ ≈ a·τ̂̃ + b + c·LP[tanh(q̇/ε)] + d·q̇̃, the joint friction (Coulomb
  and viscous) that the twin does not model; LP is the low-pass filter of the efforts and q̇̃
  the velocity through it, so that the features lag and smooth as the efforts do. ε is picked
  per joint from ``EPSILON_GRID`` by the smallest training residual: statistics for every
  candidate are gathered in one pass, so the choice uses the training logs only and still
  merges exactly.
- ``identified``: per joint τ̃ ≈ a·τ̂̃ + Ỹ_j θ_j + b + c·LP[tanh(q̇/ε)] + d·q̇̃, with Ỹ the
  joint-torque regressor (Pinocchio) through the same filter: θ_j corrects the URDF's inertial
  parameters (masses, centres of mass, inertias) as joint j sees them, which the gain a alone
  cannot (a payload or a heavier link changes the torque differently along each path). It
  needs the robot's URDF; ε is chosen as for ``friction``. Least squares with a small ridge on
  standardised columns, because most of θ is not identifiable from joint torques.
- ``…-whitened`` (``whitened=True``, a property of the score, not of the map): the same map,
  each joint's residual over its RMS s_j on the collision-free training samples (per bin of the
  joint's speed: the depth statistic), so that one noisy joint does not drown a push on a quiet
  one.

Fitting is a pure per-log step (``FrictionStats.from_arrays``) and an exact merge (``+``, Chan
et al.'s pairwise update of means and centred cross-products), like ``AffineStats``.

By concern: ``base`` (the interface), ``affine``, ``friction``, ``identified`` (one map each),
``kinds`` (by name), ``statistics``, ``solving``, ``whitening`` (the score), ``block`` (the
file's model block), ``constants``.
"""

from twincd.calibration.models.affine import AffineCalibration, AffineModel
from twincd.calibration.models.base import ResidualModel, depth_order, model_inputs
from twincd.calibration.models.block import read_model
from twincd.calibration.models.constants import (
    AFFINE,
    COEFFICIENTS,
    EPSILON_GRID,
    FRICTION_WHITENED,
    IDENTIFIED_RIDGE,
    IDENTIFIED_WHITENED,
    MIN_BIN_SAMPLES,
    SPEED_BINS,
    STATISTICS,
)
from twincd.calibration.models.friction import FrictionModel, coulomb_columns
from twincd.calibration.models.identified import IdentifiedModel
from twincd.calibration.models.kinds import (
    MODEL_CLASSES,
    MODEL_KINDS,
    fit_features,
    fit_model,
    make_model,
    model_class,
)
from twincd.calibration.models.solving import (
    FrictionSolution,
    IdentifiedSolution,
    solve_friction,
    solve_identified,
)
from twincd.calibration.models.statistics import (
    FitStats,
    FrictionStats,
    IdentifiedStats,
    SpeedStats,
    compact_regressor,
    coulomb_grid,
    motion_stats,
    one_blas_thread,
    speed_bin,
)
from twincd.calibration.models.whitening import (
    depth_noise_median,
    depth_score,
    speed_scale,
    wilson_hilferty,
)

__all__ = [
    "AFFINE",
    "COEFFICIENTS",
    "EPSILON_GRID",
    "FRICTION_WHITENED",
    "IDENTIFIED_RIDGE",
    "IDENTIFIED_WHITENED",
    "MIN_BIN_SAMPLES",
    "MODEL_CLASSES",
    "MODEL_KINDS",
    "SPEED_BINS",
    "STATISTICS",
    "AffineCalibration",
    "AffineModel",
    "FitStats",
    "FrictionModel",
    "FrictionSolution",
    "FrictionStats",
    "IdentifiedModel",
    "IdentifiedSolution",
    "IdentifiedStats",
    "ResidualModel",
    "SpeedStats",
    "compact_regressor",
    "coulomb_columns",
    "coulomb_grid",
    "depth_noise_median",
    "depth_order",
    "depth_score",
    "fit_features",
    "fit_model",
    "make_model",
    "model_class",
    "model_inputs",
    "motion_stats",
    "one_blas_thread",
    "read_model",
    "solve_friction",
    "solve_identified",
    "speed_bin",
    "speed_scale",
    "wilson_hilferty",
]
