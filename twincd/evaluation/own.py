"""Our own calibration models as ``evaluate`` methods (contract: Methods): each calibration model
kind of the registry (``twincd.calibration.models.MODEL_KINDS``) other than the seed's is a method
of the same name (``model_method``), fitted on the training logs from the same mergeable
statistics as ``twincd fit --model NAME``."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import numpy as np

from twincd.calibration import Calibration
from twincd.calibration.models import (
    AFFINE,
    EPSILON_GRID,
    MODEL_KINDS,
    ResidualModel,
    depth_order,
    make_model,
    model_class,
    model_inputs,
)
from twincd.detection.events import Event, EventRules, find_events
from twincd.detection.isolation import DEFAULT_KAPPA, LinkIsolator
from twincd.errors import DataError, NotFittedError
from twincd.evaluation.methods import MethodSkipped, ScoringMethod
from twincd.prepare.prepared import PreparedLog
from twincd.signal.edges import edge_scaled
from twincd.types import BoolArray, FloatArray


class ModelMethod(ScoringMethod):
    """A calibration model scored as detection would score it; names links of flagged runs."""

    name = "model"
    model_kind = "affine"
    unit = "sample"
    learns = True
    calibrated = True
    isolates = True

    def __init_subclass__(cls, kind: str = "", **kwargs: Any) -> None:
        """``kind``: the calibration model a subclass stands for, and its method's name."""
        super().__init_subclass__(**kwargs)
        if kind:
            cls.name = cls.model_kind = kind

    def __init__(self, kappa: float | None = None) -> None:
        self.kappa = kappa  # the isolation rule's κ (None: twincd.detection.isolation's)

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled by its kind (a kind's class is made by ``model_method``, not a module name):
        executors send methods to other processes."""
        return (_restore, (self.model_kind, dict(vars(self))))

    def check(self, logs: Sequence[PreparedLog]) -> None:
        cls = model_class(self.model_kind)[0]
        if cls.needs_coulomb and any(lg.coulomb_eps != EPSILON_GRID for lg in logs):
            raise MethodSkipped("needs logs prepared with every ε candidate's Coulomb feature")
        if cls.needs_regressor and any(lg.regressor_f is None for lg in logs):
            raise MethodSkipped("needs the robot model (URDF) of every joint, for its regressor")

    def fit(self, train: Sequence[PreparedLog]) -> ModelMethod:
        if not train:
            raise DataError("no training logs", self.name, "give collision-free training logs")
        depths = None
        if train[0].robot is not None:
            from twincd.twin.robot import child_links

            depths = child_links(train[0].robot, train[0].joint_names)[1]
        order = depth_order(depths, len(train[0].joint_names))
        self.model_: ResidualModel = make_model(self.model_kind, order).fit(train)
        return self

    def from_calibration(self, calibration: Calibration) -> ModelMethod:
        method = type(self)(self.kappa)
        method.model_ = calibration.model
        return method

    def _model(self) -> ResidualModel:
        if not hasattr(self, "model_"):
            raise NotFittedError(f"method {self.name!r} is not fitted", self.name, "call fit()")
        return self.model_

    def residual(self, log: PreparedLog) -> FloatArray:
        return self._model().residual(model_inputs(log))

    def score(self, log: PreparedLog) -> FloatArray:
        return self._model().scores(model_inputs(log), log.edge_factor)

    def isolator(self, log: PreparedLog) -> LinkIsolator | None:
        """The isolation rule on this log's joints (None without a robot model)."""
        if log.robot is None:
            return None
        from twincd.twin.robot import child_links

        links, depths = child_links(log.robot, log.joint_names)
        scale = self._model().joint_scale
        scale = np.ones(len(links)) if scale is None else scale
        return LinkIsolator(
            links, depths, scale, DEFAULT_KAPPA if self.kappa is None else self.kappa
        )

    def events(
        self, log: PreparedLog, scores: FloatArray, flags: BoolArray, hold: BoolArray
    ) -> list[Event]:
        """Detect's events, with the joint and the link each names."""
        stamps = log.states.stamp_ns
        r = edge_scaled(self.residual(log), log.edge_factor)
        # the joints weighed as detect weighs them
        evidence = self._model().whitened_residual(r, log.states.velocity)
        evidence = r if evidence is None else evidence
        iso = self.isolator(log)
        return find_events(
            flags, scores, evidence, stamps, log.joint_names, iso, EventRules(), hold
        )


# every kind but the seed's plain affine model (that one is ``proposed``, the paper's method)
OWN_KINDS = tuple(kind for kind in MODEL_KINDS if kind != AFFINE)


@functools.cache
def model_method(kind: str) -> type[ModelMethod]:
    """The ``evaluate`` method of a model kind of ``OWN_KINDS``: ``ModelMethod`` for it."""
    if kind not in OWN_KINDS:
        raise KeyError(f"no method of one's own is named {kind!r}")
    stem = "".join(part.title() for part in kind.split("-"))
    return type(f"{stem}Method", (ModelMethod,), {"__module__": __name__}, kind=kind)


def _restore(kind: str, state: dict[str, Any]) -> ModelMethod:
    cls = model_method(kind)
    method = cls.__new__(cls)
    vars(method).update(state)
    return method
