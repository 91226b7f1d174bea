"""The seed paper's method as a scoring method for ``evaluate`` (contract: Methods ``proposed``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from twincd.calibration import AffineCalibration, Calibration
from twincd.detection.score import affine_score
from twincd.errors import NotFittedError
from twincd.evaluation.methods import ScoringMethod
from twincd.pipeline import PreparedLog
from twincd.types import FloatArray


class ProposedMethod(ScoringMethod):
    """The seed paper's method: affine regression of the twin's effort, squared residual."""

    name = "proposed"
    unit = "sample"
    learns = True
    calibrated = True
    model_kind = "affine"

    def __init__(self, a: Sequence[float] | None = None, b: Sequence[float] | None = None):
        self.a = a
        self.b = b
        if a is not None and b is not None:
            self.a_: FloatArray = np.asarray(a, dtype=np.float64)
            self.b_: FloatArray = np.asarray(b, dtype=np.float64)

    def from_calibration(self, calibration: Calibration) -> ProposedMethod:
        return type(self)(list(calibration.a), list(calibration.b))

    def fit(self, train: Sequence[PreparedLog]) -> ProposedMethod:
        est = AffineCalibration().fit(train)
        self.a_, self.b_ = est.a_, est.b_
        return self

    def score(self, log: PreparedLog) -> FloatArray:
        if not hasattr(self, "a_"):
            raise NotFittedError("method 'proposed' is not fitted", "proposed", "call fit()")
        return affine_score(log.effort_f, log.sim_effort_f, self.a_, self.b_)
