"""Calibrate: the per-joint map a⊙τ̂ + b fitted on collision-free logs, and its JSON file."""

from twincd.calibration.affine import (
    AffineCalibration,
    AffineSolution,
    AffineStats,
    clean_mask,
    clean_rows,
    solve,
)
from twincd.calibration.file import SCHEMA, Calibration, Threshold, calibration_from_fit
from twincd.calibration.fitting import LogFit, fit_calibration, fit_log, merge_fits

__all__ = [
    "SCHEMA",
    "AffineCalibration",
    "AffineSolution",
    "AffineStats",
    "Calibration",
    "LogFit",
    "Threshold",
    "calibration_from_fit",
    "clean_mask",
    "clean_rows",
    "fit_calibration",
    "fit_log",
    "merge_fits",
    "solve",
]
