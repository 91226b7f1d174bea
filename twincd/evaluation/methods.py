"""The scoring-method interface shared by the paper's method and its baselines (contract: Methods).

A method is a small estimator in the scikit-learn manner: parameters in ``__init__``,
``fit(train_logs)`` returns self and sets attributes ending in ``_``, ``score(log)`` gives one
anomaly score per unit (sample or window). Thresholds (μ + kσ on validation scores) and metrics
live outside the method, so every method is judged the same way. Methods are made by name from
a registry (``make_method``); ``parse_methods`` reads ``--methods``.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from twincd.calibration.models.constants import AFFINE
from twincd.calibration.models.kinds import MODEL_KINDS
from twincd.errors import UsageError
from twincd.prepare.prepared import PreparedLog
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.detection.events import Event


# contract: Methods, in the paper's Table II order (ours first)
PAPER_METHODS = (
    "proposed",
    "naive-diff",
    "naive-mob",
    "point-ocsvm",
    "point-ae",
    "lstm-mob",
    "window-ocsvm",
    "window-ae",
)
# then our own calibration models (contract: The calibration file ``model``), beyond the paper:
# every kind of the models' registry but the paper's (``twincd.evaluation.own.OWN_KINDS``)
METHOD_NAMES = PAPER_METHODS + tuple(kind for kind in MODEL_KINDS if kind != AFFINE)


class MethodSkipped(Exception):
    """A method that cannot run on the given logs; the message is the reason shown to users."""


class ScoringMethod(ABC):
    """Base class of every method ``evaluate`` can run."""

    name: ClassVar[str]
    unit: ClassVar[str] = "sample"  # or "window"
    learns: ClassVar[bool] = True  # False: needs no training logs
    # True: the method is a calibration model; without training logs it comes from the file
    calibrated: ClassVar[bool] = False
    model_kind: ClassVar[str] = ""  # the calibration's ``model.kind`` it stands for

    def from_calibration(self, calibration: Calibration) -> ScoringMethod:
        """The method fitted as ``calibration`` is (calibrated methods only)."""
        raise MethodSkipped(f"{self.name} cannot be read from a calibration")

    def check(self, logs: Sequence[PreparedLog]) -> None:
        """Raise MethodSkipped when the method cannot run on these logs."""
        return None  # most methods run on any log with measured and simulated effort

    @abstractmethod
    def fit(self, train: Sequence[PreparedLog]) -> ScoringMethod:
        """Learn from collision-free logs; return self."""

    @abstractmethod
    def score(self, log: PreparedLog) -> FloatArray:
        """One score per unit of ``log``; higher means more likely a collision."""

    def unit_labels(self, log: PreparedLog) -> BoolArray:
        """Ground truth per unit (per sample by default)."""
        if log.labels is None:
            return np.zeros(len(log), dtype=bool)
        return log.labels

    def unit_stamps(self, log: PreparedLog) -> IntArray:
        """When each unit's decision is known: its sample's stamp (a window's last sample)."""
        return log.states.stamp_ns

    isolates: ClassVar[bool] = False  # its events name links (``events``)

    def events(
        self, log: PreparedLog, scores: FloatArray, flags: BoolArray, hold: BoolArray
    ) -> list[Event]:
        """The events ``detect`` would report for these flags (``hold``: score ≥ the release
        level), under the default ``EventRules``."""
        from twincd.detection.events import EventRules, find_events

        stamps = self.unit_stamps(log)
        quiet = np.zeros((len(flags), 1))
        return find_events(flags, scores, quiet, stamps, ("score",), None, EventRules(), hold)


# The built-in methods, name -> "module:attribute" of a factory, written out here so the
# registry never depends on which modules happen to be imported; a module is imported only
# when its method is asked for (scikit-learn and PyTorch load lazily).
BUILTIN: dict[str, str] = {
    "proposed": "twincd.evaluation.proposed:ProposedMethod",
    "naive-diff": "twincd.evaluation.baselines.naive:NaiveDiff",
    "naive-mob": "twincd.evaluation.baselines.mob:NaiveMob",
    "point-ocsvm": "twincd.evaluation.baselines.ocsvm:PointOcsvm",
    "point-ae": "twincd.evaluation.baselines.autoencoder:PointAE",
    "lstm-mob": "twincd.evaluation.baselines.lstm:LstmMob",
    "window-ocsvm": "twincd.evaluation.baselines.ocsvm:WindowOcsvm",
    "window-ae": "twincd.evaluation.baselines.autoencoder:WindowAE",
}
OWN = "twincd.evaluation.own:model_method"  # a model kind's method: model_method(kind)
_REGISTRY: dict[str, str] = dict(BUILTIN) | dict.fromkeys(METHOD_NAMES[len(PAPER_METHODS) :], OWN)


def register(name: str, target: str) -> None:
    """Add a method of one's own (``"module:attribute"`` of a factory) under ``name``."""
    _REGISTRY[name] = target


def make_method(name: str, **params: Any) -> ScoringMethod:
    """A fresh, unfitted method by its contract: Methods name."""
    target = _REGISTRY.get(name)
    if target is None:
        raise UsageError(
            f"unknown method {name!r}", "methods", f"choose from {', '.join(available())}, all"
        )
    module, attr = target.split(":")
    factory: Callable[..., Any] = getattr(importlib.import_module(module), attr)
    if target == OWN:
        factory = factory(name)  # the model kind's class
    method: ScoringMethod = factory(**params)
    return method


def available() -> list[str]:
    known = [n for n in METHOD_NAMES if n in _REGISTRY]
    return known + sorted(n for n in _REGISTRY if n not in METHOD_NAMES)


def method_for(kind: str) -> str:
    """The ``evaluate`` method that scores with a calibration model of this kind (the seed
    paper's affine model is ``proposed``)."""
    return "proposed" if kind == "affine" else kind


def parse_methods(text: str | None, default: str = "proposed") -> list[str]:
    """``--methods``: comma-separated names or ``all`` (none given: ``default``, e.g. the
    calibration's own model, ``method_for(kind)``); unknown names are a usage error."""
    names = [n.strip() for n in (text or default).split(",") if n.strip()]
    known = available()
    if "all" in names:
        return known
    unknown = [n for n in names if n not in known]
    if unknown:
        raise UsageError(
            f"unknown method(s) {', '.join(unknown)}",
            "methods",
            f"choose from {', '.join(known)}, all",
            option="methods",
        )
    return list(dict.fromkeys(names))
