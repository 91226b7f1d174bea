"""The model kinds by name: their classes, an unfitted model of a kind, what fitting it needs.

``MODEL_CLASSES`` is the one registry: a model kind is its class (``ResidualModel``: its
``name``, what it ``learned``, what it ``needs_``) and one line here. Every kind comes plain and
whitened (``MODEL_KINDS``); the file's loader (``block.read_model``), ``fit --model``, the
``evaluate`` methods of our own models (``twincd.evaluation.own``) and the conformance test
(``tests/test_model_kinds.py``) read them from here."""

from __future__ import annotations

from collections.abc import Sequence

from twincd.calibration.affine import AffineStats
from twincd.calibration.models.affine import AffineModel
from twincd.calibration.models.base import ResidualModel
from twincd.calibration.models.constants import EPSILON_GRID, SPEED_BINS
from twincd.calibration.models.friction import FrictionModel
from twincd.calibration.models.identified import IdentifiedModel
from twincd.calibration.models.statistics import (
    FitStats,
    FrictionStats,
    IdentifiedStats,
    SpeedStats,
)
from twincd.errors import UsageError
from twincd.signal.features import ModelFeatures

MODEL_CLASSES: dict[str, type[ResidualModel]] = {
    cls.name: cls for cls in (AffineModel, FrictionModel, IdentifiedModel)
}

# every kind as calibration files name it: each class plain, then whitened
MODEL_KINDS: tuple[str, ...] = tuple(
    kind for stem in MODEL_CLASSES for kind in (stem, f"{stem}-whitened")
)


def model_class(kind: str) -> tuple[type[ResidualModel], bool]:
    """The class of a model kind of ``MODEL_KINDS`` and whether it is whitened."""
    stem, whitened = kind.removesuffix("-whitened"), kind.endswith("-whitened")
    if kind not in MODEL_KINDS:
        raise UsageError(
            f"unknown calibration model {kind!r}",
            "fit",
            f"choose one of {', '.join(MODEL_KINDS)}",
            option="model",
        )
    return MODEL_CLASSES[stem], whitened


def fit_features(kind: str | None) -> ModelFeatures:
    """What fitting ``kind`` (``MODEL_KINDS``) needs from the chain; None, the best model the
    logs allow: every candidate's features, the regressor where a robot model is known."""
    if kind is None:
        return ModelFeatures(EPSILON_GRID, regressor=True, regressor_optional=True)
    cls, whitened = model_class(kind)
    return cls.fit_features(whitened)


def make_model(
    kind: str, order: Sequence[int] | None = None, speed_bins: tuple[float, ...] = SPEED_BINS
) -> ResidualModel:
    """An unfitted model of ``kind`` (``MODEL_KINDS``), its depth statistic over ``order``."""
    cls, whitened = model_class(kind)
    joints = None if order is None else tuple(int(i) for i in order)
    return cls(whitened, joints, speed_bins)


def fit_model(
    kind: str,
    affine: AffineStats,
    friction: FrictionStats | None = None,
    identified: IdentifiedStats | None = None,
    speed: SpeedStats | None = None,
    order: Sequence[int] | None = None,
) -> ResidualModel:
    """``kind`` fitted from merged statistics (``ResidualModel.solve``): a whitened model takes
    its scale per speed bin from ``speed``, or without it one per joint (scored by the sum)."""
    return make_model(kind, order).solve(FitStats(affine, speed, friction, identified))
