"""The friction map: per joint τ̃ ≈ a·τ̂̃ + b + c·LP[tanh(q̇/ε)] + d·q̇̃."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from twincd.calibration.affine import gain_share
from twincd.calibration.excitation import COULOMB, GAIN, VISCOUS, Held
from twincd.calibration.models.base import ResidualModel
from twincd.calibration.models.constants import EPSILON_GRID
from twincd.calibration.models.solving import FrictionSolution, solve_friction
from twincd.calibration.models.statistics import FitStats
from twincd.errors import DataError
from twincd.signal.features import ModelFeatures, ModelInputs
from twincd.types import BoolArray, FloatArray


def coulomb_columns(
    coulomb_f: FloatArray, coulomb_eps: Sequence[float], epsilon: FloatArray
) -> FloatArray:
    """(N, D): each joint's filtered tanh(q̇/ε_j) out of ``coulomb_f`` (N, E, D) for the ε
    values ``coulomb_eps``."""
    eps = [float(e) for e in coulomb_eps]
    try:
        index = np.array([eps.index(float(e)) for e in epsilon], dtype=np.intp)
    except ValueError:
        raise DataError(
            "the prepared samples lack the Coulomb feature of an ε the model uses",
            f"ε {', '.join(f'{e:g}' for e in epsilon)} vs prepared {', '.join(map(str, eps))}",
            "prepare logs with the calibration's settings (Setup.from_calibration)",
        ) from None
    out: FloatArray = coulomb_f[:, index, np.arange(len(index))]
    return out


class FrictionModel(ResidualModel):
    """Per joint τ̃ ≈ a·τ̂̃ + b + c·LP[tanh(q̇/ε)] + d·q̇̃ (ε per joint from ``EPSILON_GRID``)."""

    name = "friction"
    needs_coulomb = True
    learned = (*ResidualModel.learned, "c", "d", "epsilon")

    c_: FloatArray
    d_: FloatArray
    epsilon_: FloatArray

    @property
    def features(self) -> ModelFeatures:
        """The Coulomb features at the ε its joints use (with the filtered velocity)."""
        self._check()
        return ModelFeatures(coulomb_eps=tuple(sorted({float(e) for e in self.epsilon_})))

    def _solve_map(self, stats: FitStats) -> None:
        if stats.friction is None:
            raise DataError(
                f"the {self.kind} model needs Coulomb features for every ε candidate",
                "fit",
                "prepare the logs with the model's fit_features",
            )
        self._set_friction(solve_friction(stats.friction, stats.resting, stats.independent), stats)

    def _set_friction(
        self, fr: FrictionSolution, stats: FitStats, theta: BoolArray | None = None
    ) -> None:
        self.a_, self.b_, self.c_, self.d_, self.epsilon_ = fr.a, fr.b, fr.c, fr.d, fr.epsilon
        self.r2_, self.rmse_ = fr.r2, fr.rmse
        self.n_samples_ = stats.affine.n
        held = np.zeros((len(fr.a), 3), dtype=bool) if fr.held is None else fr.held
        share = gain_share(stats.affine)
        resting = np.zeros(len(fr.a), dtype=bool) if stats.resting is None else stats.resting
        self.held_ = Held(
            held[:, GAIN],
            held[:, COULOMB],
            held[:, VISCOUS],
            resting,
            share,
            theta,
            fr.scarce,
            stats.independent,
        )

    def predict(self, inputs: ModelInputs) -> FloatArray:
        out = super().predict(inputs)
        if inputs.coulomb_f is None or inputs.velocity_f is None:
            raise DataError(
                f"the {self.kind} model needs the filtered velocity and Coulomb features",
                "scoring",
                "prepare logs with the model's features (ResidualModel.features)",
            )
        coulomb = coulomb_columns(inputs.coulomb_f, inputs.coulomb_eps, self.epsilon_)
        # (τ̂ term + Coulomb) + viscous, in this order (the order fixes the rounding)
        with_friction: FloatArray = out + self.c_ * coulomb + self.d_ * inputs.velocity_f
        return with_friction

    def residual_weights(self, params: int, coulomb: int) -> FloatArray:
        if coulomb != len(EPSILON_GRID):
            raise DataError(
                f"the {self.kind} model's whitening needs every ε candidate's Coulomb feature",
                "fit",
                "prepare the logs with the model's fit_features",
            )
        w = super().residual_weights(params, coulomb)
        w[:, params + 1] = -self.d_
        at = [EPSILON_GRID.index(float(x)) for x in self.epsilon_]
        w[np.arange(len(w)), params + 2 + np.array(at, dtype=np.intp)] = -self.c_
        return w
