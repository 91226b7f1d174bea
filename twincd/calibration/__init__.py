"""Calibrate: a model of the measured effort from the twin's, fitted on collision-free logs, and
its JSON file."""

from twincd.calibration.affine import (
    AffineSolution,
    AffineStats,
    clean_mask,
    clean_rows,
    fit_mask,
    fit_rows,
    solve,
)
from twincd.calibration.file import (
    SCHEMA,
    Calibration,
    FitInfo,
    Threshold,
    calibration_from_fit,
)
from twincd.calibration.fitting import LogFit, fit_log, merge_fits
from twincd.calibration.models import (
    AffineCalibration,
    AffineModel,
    FitStats,
    FrictionModel,
    IdentifiedModel,
    ResidualModel,
    make_model,
)
from twincd.calibration.reading import upgrade_v1, upgrade_v2

__all__ = [
    "SCHEMA",
    "AffineCalibration",
    "AffineModel",
    "AffineSolution",
    "AffineStats",
    "Calibration",
    "FitInfo",
    "FitStats",
    "FrictionModel",
    "IdentifiedModel",
    "LogFit",
    "ResidualModel",
    "Threshold",
    "calibration_from_fit",
    "clean_mask",
    "clean_rows",
    "fit_log",
    "fit_mask",
    "fit_rows",
    "make_model",
    "merge_fits",
    "solve",
    "upgrade_v1",
    "upgrade_v2",
]
