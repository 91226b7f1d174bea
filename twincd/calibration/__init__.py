"""Calibrate: the per-joint map a⊙τ̂ + b fitted on collision-free logs, and its JSON file."""

from twincd.calibration.affine import (
    AffineCalibration,
    AffineSolution,
    AffineStats,
    clean_mask,
    solve,
)
from twincd.calibration.file import SCHEMA, Calibration, Threshold, calibration_from_fit
from twincd.calibration.setup import Setup, fit_calibration

__all__ = [
    "SCHEMA",
    "AffineCalibration",
    "AffineSolution",
    "AffineStats",
    "Calibration",
    "Setup",
    "Threshold",
    "calibration_from_fit",
    "clean_mask",
    "fit_calibration",
    "solve",
]
