"""The interface of every calibration model (``ResidualModel``: ``stats`` → ``merge`` →
``solve``, then ``predict``, ``residual`` and ``score``), and what it reads from a prepared log."""

from __future__ import annotations

import logging
import operator
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from functools import reduce
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

import numpy as np

from twincd.calibration.affine import fit_mask, solve
from twincd.calibration.excitation import Held, check_motion, independent_samples
from twincd.calibration.models.constants import (
    AFFINE,
    COEFFICIENTS,
    EPSILON_GRID,
    MIN_SCALE,
    SPEED_BINS,
)
from twincd.calibration.models.statistics import FitStats, speed_bin
from twincd.calibration.models.whitening import depth_score, speed_scale
from twincd.errors import DataError, NotFittedError
from twincd.signal.features import ModelFeatures, ModelInputs
from twincd.types import BoolArray, FloatArray

if TYPE_CHECKING:
    from twincd.prepare.prepared import PreparedLog


log = logging.getLogger("twincd")


M = TypeVar("M", bound="ResidualModel")


class ResidualModel:
    """A map from the twin's effort (and the model's other prepared inputs) to the measured one,
    and the score of its residual; one subclass per model kind (scikit-learn style: parameters
    in ``__init__``, never changed by fitting; learned values end in ``_``).

    Fitting is ``stats`` per log or block, an exact merge (``merge``, ``+``), then ``solve``.
    Whitening is a property of the score: ``whitened`` models divide each joint's residual by
    its training RMS, per bin of the joint's speed (``speed_bins``; the depth statistic over the
    joints in ``order``, base first), or one per joint (``statistic`` "sum": Σ_j (r_j/s_j)²);
    the others score Σ_j r_j².
    """

    name: ClassVar[str] = AFFINE  # the kind's stem in calibration files
    needs_coulomb: ClassVar[bool] = False  # prepared with the Coulomb features of every ε
    needs_regressor: ClassVar[bool] = False  # prepared with the joint-torque regressor
    # what it learns per joint, each a number or a list of numbers (``coefficients``): what a
    # calibration file holds of it and ``read_model`` reads back
    learned: ClassVar[tuple[str, ...]] = ("a", "b", "scale")

    a_: FloatArray
    b_: FloatArray
    scale_: FloatArray | None
    r2_: FloatArray | None
    rmse_: FloatArray | None
    n_samples_: int
    fit_s_: float
    joint_names_: tuple[str, ...]  # the joints of the logs ``fit`` saw
    held_: Held  # what the logs' motion did not determine (set by ``solve``)

    def __init__(
        self,
        whitened: bool = False,
        order: Sequence[int] | None = None,
        speed_bins: tuple[float, ...] = SPEED_BINS,
    ) -> None:
        self.whitened = whitened
        self.order = order
        self.speed_bins = speed_bins

    @property
    def kind(self) -> str:
        """The kind as calibration files name it (``MODEL_KINDS``)."""
        return f"{self.name}-whitened" if self.whitened else self.name

    # ------------------------------------------------------------------ its features

    @classmethod
    def fit_features(cls, whitened: bool) -> ModelFeatures:
        """What fitting a model of this class needs from the chain: the Coulomb features of
        every ε candidate (friction), the whole regressor (identified), the speed bins'
        statistics (whitened)."""
        return ModelFeatures(
            coulomb_eps=EPSILON_GRID if cls.needs_coulomb else (),
            regressor=cls.needs_regressor,
            speed_stats=whitened,
        )

    @property
    def features(self) -> ModelFeatures:
        """What this fitted model scores from (the chain computes exactly these)."""
        self._check()
        return ModelFeatures()

    # ------------------------------------------------------------------ fitting

    def stats(self, inputs: ModelInputs, clean: BoolArray) -> FitStats:
        """The statistics this model fits from, of prepared samples (``predict``'s inputs plus
        ``effort_f`` and the raw ``velocity``), rows where ``clean`` holds."""
        return FitStats.from_inputs(inputs, clean)

    @staticmethod
    def merge(parts: Iterable[FitStats]) -> FitStats:
        """Statistics of several logs or blocks together (exact, in any order)."""
        return reduce(operator.add, parts)

    def solve(self: M, stats: FitStats) -> M:
        """Fit from merged statistics; a whitened model also takes its scale from them (per
        speed bin with ``stats.speed``, else one per joint). Logs in which no joint moves are
        refused; coefficients their motion does not determine are held (``held_``,
        ``twincd.calibration.excitation``)."""
        check_motion(stats.motion, getattr(self, "joint_names_", None))
        self._solve_map(stats)
        self.scale_ = None
        if self.whitened:
            assert self.rmse_ is not None
            speed = stats.speed
            if speed is None:
                self.scale_ = self.rmse_
            else:
                w = self.residual_weights(speed.params, speed.coulomb)
                self.scale_ = speed_scale(speed, w, self.b_, self.rmse_)
        return self

    def fit(self: M, logs: Iterable[PreparedLog]) -> M:
        """Fit on the collision-free samples of prepared ``logs``, one at a time (may be lazy);
        ``fit_s_`` times the statistics and the solve, as the paper times training."""
        elapsed = 0.0
        parts = []
        for log_ in logs:
            start = time.perf_counter()
            part = self.stats(model_inputs(log_), fit_mask(log_))
            if log_.period_s:  # the samples the filter leaves independent
                cutoff = log_.lowpass.cutoff_hz
                count = independent_samples(part.affine.n, cutoff, log_.period_s)
                part = replace(part, independent=count)
            parts.append(part)
            self.joint_names_ = log_.joint_names
            elapsed += time.perf_counter() - start
        if not parts:
            raise DataError("no logs to fit", "fit", "give at least one collision-free log")
        start = time.perf_counter()
        self.solve(self.merge(parts))
        self.fit_s_ = elapsed + time.perf_counter() - start
        return self

    def _solve_map(self, stats: FitStats) -> None:
        sol = solve(stats.affine, stats.independent)
        self.a_, self.b_, self.r2_, self.rmse_ = sol.a, sol.b, sol.r2, sol.rmse
        self.n_samples_ = stats.affine.n
        none = np.zeros_like(sol.held)
        resting = none if stats.resting is None else stats.resting
        few = np.stack([sol.scarce, none, none, none], axis=1)
        self.held_ = Held(
            sol.held, none, none, resting, sol.gain_share, None, few, stats.independent
        )

    def with_coefficients(
        self: M,
        coefficients: Mapping[str, FloatArray | None],
        r2: FloatArray | None = None,
        rmse: FloatArray | None = None,
    ) -> M:
        """This model fitted with stored ``coefficients`` (its ``learned``: what a calibration
        file holds)."""
        for key in self.learned:
            setattr(self, f"{key}_", coefficients.get(key))
        self.r2_, self.rmse_ = r2, rmse
        return self

    def coefficients(self) -> dict[str, FloatArray | None]:
        """What this kind learns (``learned``), in the file's order (``COEFFICIENTS`` first),
        None where a model of it has none (a plain model's ``scale``)."""
        self._check()
        keys = [k for k in COEFFICIENTS if k in self.learned]
        keys += [k for k in self.learned if k not in keys]
        return {key: getattr(self, f"{key}_", None) for key in keys}

    def to_dict(self, joint_names: Sequence[str]) -> dict[str, Any]:
        """The model's block of the calibration file (``model``, read back by ``read_model``):
        its kind, how it scores (``statistic``; the depth statistic's ``speed_bins``) and each
        joint's coefficients."""
        coefficients = self.coefficients()
        statistic: dict[str, Any] = {"statistic": self.statistic}
        if self.statistic == "depth":
            statistic["speed_bins"] = list(self.speed_bins)

        def joint(i: int) -> dict[str, Any]:
            out: dict[str, Any] = {}
            for key, values in coefficients.items():
                if values is not None:
                    out[key] = values[i].tolist() if values.ndim == 2 else float(values[i])
            return out

        return {
            "kind": self.kind,
            **statistic,
            "joints": {n: joint(i) for i, n in enumerate(joint_names)},
        }

    # ------------------------------------------------------------------ the map

    def predict(self, inputs: ModelInputs) -> FloatArray:
        """The twin's effort mapped to the real robot's, (N, D), from prepared samples
        (``sim_effort_f``; friction models also ``velocity_f``, ``coulomb_f`` and
        ``coulomb_eps``; identified ones ``regressor_f`` or ``regressor_effort_f``)."""
        self._check()
        out: FloatArray = self.a_ * np.asarray(inputs.sim_effort_f, dtype=np.float64) + self.b_
        return out

    def residual(self, inputs: ModelInputs, predicted: FloatArray | None = None) -> FloatArray:
        """τ̃ − f(τ̂̃, …), (N, D) (``predicted``: ``predict(inputs)``, when already known)."""
        twin = self.predict(inputs) if predicted is None else predicted
        out: FloatArray = np.asarray(inputs.measured, np.float64) - twin
        return out

    def residual_weights(self, params: int, coulomb: int) -> FloatArray:
        """(D, K) the residual τ̃ − f(…) + b as weights on the columns of ``SpeedStats`` with
        ``params`` regressor entries and ``coulomb`` Coulomb features per joint."""
        w = np.zeros((len(self.a_), params + 3 + coulomb))
        w[:, 0] = -self.a_
        w[:, -1] = 1.0
        return w

    def _check(self) -> None:
        if not hasattr(self, "a_"):
            raise NotFittedError(
                f"the {self.kind} model is not fitted", type(self).__name__, "call fit()"
            )

    # ------------------------------------------------------------------ the score

    @property
    def statistic(self) -> str:
        """How residuals become a score (one of ``STATISTICS``; "sum" for unwhitened models)."""
        scale = getattr(self, "scale_", None)
        return "depth" if scale is not None and scale.ndim == 2 else "sum"

    def score(self, residual: FloatArray, velocity: FloatArray | None = None) -> FloatArray:
        """(N,) Σ_j r_j² (unwhitened), the depth statistic of r_j / s_j(|q̇_j|) (whitened,
        from the (N, D) joint ``velocity``), or Σ_j (r_j/s_j)² (whitened, one scale per joint)."""
        scale = self.scale_
        if scale is None or scale.ndim == 1:
            r = residual if scale is None else residual / np.maximum(scale, MIN_SCALE)
            out: FloatArray = np.einsum("ij,ij->i", r, r)
            return out
        return self.weigh(residual, velocity)[0]

    def weigh(
        self, residual: FloatArray, velocity: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """(N,) scores and the (N, D) evidence events weigh joints by: the residual whitened by
        speed for the depth statistic (computed once for both), else the residual itself."""
        if self.statistic != "depth":
            return self.score(residual), residual
        whitened = self._by_speed(residual, velocity)
        order = None if self.order is None else np.asarray(self.order, dtype=np.intp)
        return depth_score(whitened, order), whitened

    def whitened_residual(
        self, residual: FloatArray, velocity: FloatArray | None
    ) -> FloatArray | None:
        """(N, D) each joint's residual over its noise scale at its speed, the evidence the
        depth statistic weighs (None for models without speed bins)."""
        if self.statistic != "depth":
            return None
        return self._by_speed(residual, velocity)

    def _by_speed(self, residual: FloatArray, velocity: FloatArray | None) -> FloatArray:
        assert self.scale_ is not None
        if velocity is None:
            raise DataError(
                f"the {self.kind} model scores with the joints' speeds",
                "scoring",
                "pass the joint velocity with the residual",
            )
        bins = speed_bin(np.asarray(velocity, dtype=np.float64), self.speed_bins)
        joints = np.arange(residual.shape[1])
        out: FloatArray = residual / np.maximum(self.scale_, MIN_SCALE)[joints[None, :], bins]
        return out

    def in_noise_units(
        self, residual: FloatArray, velocity: FloatArray | None = None
    ) -> FloatArray | None:
        """(N, D) each joint's residual over the noise the fit left it: over its scale at its
        speed (the depth statistic), its whitening scale, or its training RMSE (unwhitened);
        on clean data the calibration fits, an RMS of about 1 per joint. None when the model
        records no such scale."""
        if self.statistic == "depth":
            return self._by_speed(residual, velocity)
        scale = self.scale_ if self.scale_ is not None else self.rmse_
        if scale is None:
            return None
        out: FloatArray = residual / np.maximum(np.asarray(scale, np.float64), MIN_SCALE)
        return out

    def scores(self, inputs: ModelInputs, edge_factor: FloatArray | None = None) -> FloatArray:
        """Per-sample scores of prepared samples (``predict``'s inputs, ``effort_f``, and the raw
        ``velocity`` for the depth statistic), each judged with the noise of its distance from
        its segment's ends (``edge_factor``, the chain's: ``twincd.signal.edges``)."""
        from twincd.signal.edges import edge_scaled

        return self.score(edge_scaled(self.residual(inputs), edge_factor), inputs.velocity)

    @property
    def joint_scale(self) -> FloatArray | None:
        """The per-joint scale isolation divides an event's residual by: ones for a model
        with speed bins (its evidence is already ``whitened_residual``), the flat whitening
        scale, else the training residual RMS (None when unknown)."""
        if self.scale_ is not None:
            return self.scale_ if self.scale_.ndim == 1 else np.ones(len(self.scale_))
        return self.rmse_


def model_inputs(log: PreparedLog) -> ModelInputs:
    """What a ``ResidualModel`` reads, from a whole prepared log."""
    return ModelInputs(
        effort_f=log.effort_f,
        sim_effort_f=log.twin_f,
        velocity_f=log.velocity_f,
        coulomb_f=log.coulomb_f,
        coulomb_eps=log.coulomb_eps,
        regressor_f=log.regressor_f,
        regressor_effort_f=log.regressor_effort_f,
        regressor_theta=log.features.theta,
        velocity=log.states.velocity,
        position=log.states.position,
    )


def depth_order(depths: Sequence[int] | None, joints: int) -> tuple[int, ...]:
    """The joints base first: by their depth in the kinematic tree when known (ties keep the
    joints' order), else as they come."""
    if depths is None:
        return tuple(range(joints))
    return tuple(int(i) for i in np.argsort(np.asarray(depths), kind="stable"))
