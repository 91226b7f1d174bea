"""The identified map: the friction map plus the URDF's inertial parameters corrected as each
joint sees them, Ỹ_j θ_j."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from twincd.calibration.models.friction import FrictionModel
from twincd.calibration.models.solving import solve_identified
from twincd.calibration.models.statistics import FitStats
from twincd.errors import DataError, JointMismatchError
from twincd.signal.features import ModelFeatures, ModelInputs
from twincd.types import FloatArray


class IdentifiedModel(FrictionModel):
    """Per joint τ̃ ≈ a·τ̂̃ + Ỹ_j θ_j + b + c·LP[tanh(q̇/ε)] + d·q̇̃: the friction model plus
    the URDF's inertial parameters corrected as each joint sees them (``solve_identified``)."""

    name = "identified"
    needs_regressor = True
    learned = (*FrictionModel.learned, "theta")

    theta_: FloatArray  # (D, P): per joint, the regressor's weights

    @property
    def features(self) -> ModelFeatures:
        """Its Coulomb features, and Ỹθ filtered per joint with its own θ."""
        return replace(super().features, regressor=True, theta=self.theta_)

    def _solve_map(self, stats: FitStats) -> None:
        if stats.friction is None:
            super()._solve_map(stats)  # the same error: the features of every ε are missing
        if stats.identified is None:
            raise DataError(
                f"the {self.kind} model needs the joint-torque regressor's statistics",
                "fit",
                "prepare the logs with the robot model (fit_features)",
            )
        ident = solve_identified(stats.identified, stats.resting, stats.independent)
        self._set_friction(ident.friction, stats, ident.theta_held)
        self.theta_ = ident.theta

    def predict(self, inputs: ModelInputs) -> FloatArray:
        out = super().predict(inputs)
        effort = inputs.regressor_effort_f
        if effort is not None:  # Ỹθ filtered as one channel per joint (twincd.prepare.chain)
            theta = inputs.regressor_theta
            if theta is None or theta.shape != self.theta_.shape or np.any(theta != self.theta_):
                raise DataError(
                    f"the samples carry Ỹθ filtered with another θ than this {self.kind} model's",
                    "scoring",
                    "prepare logs with the model's own features (ResidualModel.features)",
                )
            summed: FloatArray = out + np.asarray(effort, dtype=np.float64)
            return summed
        regressor = inputs.regressor_f
        regressor_mask = inputs.regressor_mask
        if regressor is None:
            raise DataError(
                f"the {self.kind} model needs the filtered joint-torque regressor",
                "scoring",
                "prepare logs with the model's features (ResidualModel.features)",
            )
        if regressor_mask is not None and np.ndim(regressor) == 2:
            if np.shape(regressor_mask) != self.theta_.shape:
                raise self._theta_mismatch(np.shape(regressor_mask)[1])
            from twincd.twin.dynamics import regressor_effort

            y = np.asarray(regressor, dtype=np.float64)
            return out + regressor_effort(y, self.theta_, np.asarray(regressor_mask, dtype=bool))
        if np.shape(regressor)[1:] != self.theta_.shape:
            raise self._theta_mismatch(np.shape(regressor)[-1])
        inertial: FloatArray = np.einsum("ndp,dp->nd", regressor, self.theta_)
        return out + inertial

    def residual_weights(self, params: int, coulomb: int) -> FloatArray:
        if self.theta_.shape[1] != params:
            raise self._theta_mismatch(params)
        w = super().residual_weights(params, coulomb)
        w[:, 1 : params + 1] = -self.theta_
        return w

    def _theta_mismatch(self, params: int) -> JointMismatchError:
        return JointMismatchError(
            f"the calibration's theta holds {self.theta_.shape[1]} inertial parameters "
            f"per joint, the robot model has {params}",
            "scoring",
            "use a calibration fitted with this robot's URDF, or re-run `twincd fit`",
        )
