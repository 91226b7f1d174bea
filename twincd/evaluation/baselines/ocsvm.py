"""One-class SVM baselines (paper IV-B 3 and 6): scikit-learn's OneClassSVM, RBF kernel, ν = 0.1,
on min–max normalised τ_ext, per sample (``point-ocsvm``) or per 16-sample window
(``window-ocsvm``, Park et al.). Score = −decision_function: higher is more anomalous.

RBF SVM training grows roughly quadratically with the number of rows, so training uses at most
``max_train`` rows: a seeded uniform random subsample when there are more (``note`` then says
so). The subsample's seed is ``subsample_seed``, deliberately not ``seed``: the SVM itself is
deterministic, so ``evaluate --repeats`` runs it once, as the paper reports it. The default cap,
20 000 rows, trains in about 5 s on this project's 2-core machine (29 521 rows: 14 s); the
paper's whole training set (30 paths, about 85 000 samples) took 56 s on a 10-core desktop.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from twincd.errors import NotFittedError
from twincd.evaluation.baselines.mob import DEFAULT_GAIN, MobFeatureMethod
from twincd.evaluation.baselines.windows import WINDOW_SIZE
from twincd.signal.filters import LowPass
from twincd.types import FloatArray

DEFAULT_NU = 0.1
DEFAULT_MAX_TRAIN = 20_000


class _Ocsvm(MobFeatureMethod):
    def __init__(
        self,
        nu: float = DEFAULT_NU,
        max_train: int | None = DEFAULT_MAX_TRAIN,
        gain: float = DEFAULT_GAIN,
        lowpass: LowPass | None = None,
        stride: int = WINDOW_SIZE,
        subsample_seed: int = 0,
    ) -> None:
        super().__init__(gain=gain, lowpass=lowpass, stride=stride)
        self.nu = nu
        self.max_train = max_train
        self.subsample_seed = subsample_seed
        self.svm_: object | None = None

    def _fit_scaled(self, x: FloatArray) -> None:
        from sklearn.svm import OneClassSVM

        x = self._training_rows(x, self.max_train, self.subsample_seed, "max_train")
        self.svm_ = OneClassSVM(kernel="rbf", nu=self.nu).fit(x)

    def _score_scaled(self, x: FloatArray) -> FloatArray:
        if self.svm_ is None:
            raise NotFittedError(f"{self.name} used before fit()", self.name, "call fit() first")
        decision = self.svm_.decision_function(x)  # type: ignore[attr-defined]
        out: FloatArray = -np.asarray(decision, dtype=np.float64)
        return out


class PointOcsvm(_Ocsvm):
    """OCSVM on τ_ext(t) per sample (paper IV-B 3). ``stride`` is unused."""

    name = "point-ocsvm"
    unit = "sample"
    window: ClassVar[int] = 1


class WindowOcsvm(_Ocsvm):
    """OCSVM on windows τ_ext(t−15), …, τ_ext(t): 16 × joints inputs (paper IV-B 6).

    Windows are taken every ``stride`` samples (default 16: adjacent, non-overlapping, which
    matches the paper's Table II timings: window OCSVM tests ~100× faster than point OCSVM).
    """

    name = "window-ocsvm"
    unit = "window"
    window: ClassVar[int] = WINDOW_SIZE
