"""What a calibration model reads from the prepared stream, typed: ``ModelFeatures`` says which
filtered inputs the chain computes for a model (``twincd.prepare.chain.build_chain``),
``ModelInputs`` holds them, sample by sample, for the model to fit or score, and
``FittedModel`` is what the chain asks of a fitted model (its features, its prediction).

A fitted model declares its own features (``ResidualModel.features``: its ε, its regressor
weights θ), so what scores a log is always the model itself; a fit asks for the features of
every candidate (``twincd.calibration.models.fit_features``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, cast

import numpy as np

from twincd.types import BoolArray, FloatArray, IntArray


@dataclass(frozen=True)
class ModelFeatures:
    """The filtered inputs a model needs from the chain besides τ̃ and τ̂̃.

    ``coulomb_eps``: the ε of the Coulomb features LP[tanh(q̇/ε)] (with the filtered velocity;
    friction models). ``regressor``: the filtered joint-torque regressor Ỹ (identified models);
    ``regressor_optional``: left out, rather than a log refused, where no robot model is known.
    ``theta``: a fitted identified model's (D, P) weights, so that only Ỹθ is filtered, one
    channel per joint, instead of Ỹ's entries. ``speed_stats``: a fit gathers each joint's
    residual statistics per bin of its speed (the whitened models' noise scale)."""

    coulomb_eps: tuple[float, ...] = ()
    regressor: bool = False
    regressor_optional: bool = False
    theta: FloatArray | None = field(default=None, compare=False)
    speed_stats: bool = True


@dataclass(frozen=True)
class ModelInputs:
    """Prepared samples as a model reads them, (N, D) per joint unless said.

    ``effort_f`` τ̃ and ``sim_effort_f`` τ̂̃; ``velocity_f`` q̇̃ and ``coulomb_f`` (N, E, D) the
    Coulomb features for the ε of ``coulomb_eps``; the regressor either whole (N, D, P) or its
    entries where ``regressor_mask`` (D, P) holds (N, kept), or ``regressor_effort_f`` Ỹθ per
    joint; the raw ``velocity`` (the depth statistic's speed bins) and ``position``."""

    sim_effort_f: FloatArray
    effort_f: FloatArray | None = None
    velocity_f: FloatArray | None = None
    coulomb_f: FloatArray | None = None
    coulomb_eps: tuple[float, ...] = ()
    regressor_f: FloatArray | None = None
    regressor_mask: BoolArray | None = None
    regressor_effort_f: FloatArray | None = None
    regressor_theta: FloatArray | None = None  # the θ ``regressor_effort_f`` was filtered with
    velocity: FloatArray | None = None
    position: FloatArray | None = None
    # (N,) int ns: the samples' stamps, for a model whose map depends on time (the cross-fit's
    # models of time folds, ``twincd.calibration.crossfit``)
    stamp_ns: IntArray | None = None

    @classmethod
    def of(
        cls,
        columns: Mapping[str, Any],
        coulomb_eps: tuple[float, ...] = (),
        regressor_mask: BoolArray | None = None,
        regressor_theta: FloatArray | None = None,
    ) -> ModelInputs:
        """The inputs among named columns (a ``Frame`` of the prepared stream, or a grid's
        nodes); ``coulomb_eps`` the ε of their ``coulomb_f``, ``regressor_mask`` the entries of
        their (N, kept) ``regressor_f``, ``regressor_theta`` the θ of their
        ``regressor_effort_f``."""

        def get(key: str) -> Any:
            value = columns.get(key)
            return None if value is None else np.asarray(value)

        return cls(
            sim_effort_f=np.asarray(columns["sim_effort_f"]),
            effort_f=get("effort_f"),
            velocity_f=get("velocity_f"),
            coulomb_f=get("coulomb_f"),
            coulomb_eps=tuple(float(e) for e in coulomb_eps),
            regressor_f=get("regressor_f"),
            regressor_mask=regressor_mask,
            regressor_effort_f=get("regressor_effort_f"),
            regressor_theta=regressor_theta,
            velocity=get("velocity"),
            position=get("position"),
            stamp_ns=get("stamp_ns"),
        )

    def take(self, rows: BoolArray | IntArray) -> ModelInputs:
        """These inputs at ``rows`` only (a mask or indices of the samples): every per-sample
        array, the masks and θ as they are."""
        n = len(self.sim_effort_f)
        per_sample = {
            name: value[rows]
            for name, value in vars(self).items()
            if isinstance(value, np.ndarray)
            and name not in ("regressor_mask", "regressor_theta")
            and value.ndim >= 1
            and len(value) == n
        }
        return replace(self, **cast(Any, per_sample))

    def columns(self) -> dict[str, FloatArray]:
        """The per-sample arrays by name (those present), as ``of`` reads them back."""
        names = ("sim_effort_f", "effort_f", "velocity_f", "coulomb_f", "regressor_f",
                 "regressor_effort_f", "velocity", "position")  # fmt: skip
        pairs = ((name, getattr(self, name)) for name in names)
        return {name: value for name, value in pairs if value is not None}

    @property
    def measured(self) -> FloatArray:
        """τ̃, which a residual and a fit need (a ``DataError`` when it is missing)."""
        if self.effort_f is None:
            from twincd.errors import DataError

            raise DataError(
                "the inputs lack the measured effort τ̃",
                "scoring",
                "pass the filtered measured effort (effort_f) with the twin's",
            )
        return self.effort_f


class FittedModel(Protocol):
    """What preparing and scoring a log asks of a fitted model
    (``twincd.calibration.models.ResidualModel`` is one): the features the chain computes for
    it, its prediction of the measured effort from them and its residual. The chain runs below
    the models, so it knows them only through this."""

    @property
    def features(self) -> ModelFeatures: ...

    def predict(self, inputs: ModelInputs) -> FloatArray: ...

    def residual(self, inputs: ModelInputs, predicted: FloatArray | None = None) -> FloatArray:
        """The measured effort less the model's prediction (what its score judges)."""
        ...
