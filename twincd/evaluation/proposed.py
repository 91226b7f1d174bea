"""The seed paper's method as a scoring method for ``evaluate`` (contract: Methods ``proposed``):
the affine model, unwhitened."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from twincd.calibration import AffineCalibration, Calibration
from twincd.calibration.models import AffineModel, ResidualModel, model_inputs
from twincd.errors import NotFittedError
from twincd.evaluation.methods import ScoringMethod
from twincd.prepare.prepared import PreparedLog
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
            coefficients = {"a": np.asarray(a, dtype=np.float64), "b": np.asarray(b, np.float64)}
            self.model_: ResidualModel = AffineModel().with_coefficients(coefficients)

    def from_calibration(self, calibration: Calibration) -> ProposedMethod:
        return type(self)(list(calibration.model.a_), list(calibration.model.b_))

    def fit(self, train: Sequence[PreparedLog]) -> ProposedMethod:
        self.model_ = AffineCalibration().fit(train)
        return self

    @property
    def a_(self) -> FloatArray:
        """The fitted gains a (the affine model's)."""
        return self._model().a_

    @property
    def b_(self) -> FloatArray:
        return self._model().b_

    def _model(self) -> ResidualModel:
        if not hasattr(self, "model_"):
            raise NotFittedError("method 'proposed' is not fitted", "proposed", "call fit()")
        return self.model_

    def score(self, log: PreparedLog) -> FloatArray:
        return self._model().scores(model_inputs(log), log.edge_factor)
