"""The seed paper's affine map τ̃ ≈ a⊙τ̂̃ + b as a model, and on its own as an estimator."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from twincd.calibration.affine import AffineStats, solve, warn_ill_conditioned
from twincd.calibration.models.base import ResidualModel, log
from twincd.calibration.models.statistics import FitStats, motion_stats
from twincd.signal.features import ModelInputs
from twincd.types import BoolArray, FloatArray


class AffineModel(ResidualModel):
    """The seed paper's τ̃ ≈ a⊙τ̂̃ + b (eq. 3–4); unwhitened, its score is eq. 5."""

    def stats(self, inputs: ModelInputs, clean: BoolArray) -> FitStats:
        """Only the affine statistics, unless the whitening scale needs the speed bins."""
        if self.whitened:
            return super().stats(inputs, clean)
        affine = AffineStats.from_arrays(inputs.sim_effort_f, inputs.measured, clean)
        return FitStats(affine, motion=motion_stats(inputs, clean))


class AffineCalibration(AffineModel):
    """The paper's a, b as an estimator on its own (the affine model, unwhitened), which also
    warns about joints whose slope is badly conditioned and predicts from the twin's effort
    alone. Learned attributes as ``AffineModel``'s, and ``stats_`` (the merged AffineStats)."""

    def __init__(
        self, joint_names: Sequence[str] | None = None, warn_ill_conditioned: bool = True
    ) -> None:
        super().__init__()
        self.joint_names = joint_names
        self.warn_ill_conditioned = warn_ill_conditioned

    def fit_arrays(
        self, effort_f: FloatArray, sim_effort_f: FloatArray, mask: BoolArray | None = None
    ) -> AffineCalibration:
        """Fit from arrays in memory: the filtered measured and twin efforts (N, D), and which
        samples are collision-free (``mask``; None: every one) — the estimator on its own."""
        return self.fit_stats(AffineStats.from_arrays(sim_effort_f, effort_f, mask))

    def fit_stats(self, stats: AffineStats) -> AffineCalibration:
        """Fit from statistics merged elsewhere (e.g. computed per log on workers)."""
        self.fit_s_ = 0.0
        return self.solve(FitStats(stats))

    def solve(self, stats: FitStats) -> AffineCalibration:
        super().solve(stats)
        self.stats_ = stats.affine
        if self.warn_ill_conditioned:
            sol = solve(stats.affine)
            names = self.joint_names or getattr(self, "joint_names_", None)
            warn_ill_conditioned(names, stats.affine, sol.ill_conditioned, sol.a)
            labels = list(names or [f"#{i + 1}" for i in range(len(sol.a))])
            for line in self.held_.messages(labels, self.kind):
                log.warning("%s", line)
        return self

    def predict(self, inputs: ModelInputs | FloatArray) -> FloatArray:
        """a⊙τ̂̃ + b: the twin's effort adjusted to the real robot (``inputs``: prepared
        samples, or the twin's effort τ̂̃ alone)."""
        if isinstance(inputs, ModelInputs):
            return super().predict(inputs)
        return super().predict(ModelInputs(sim_effort_f=np.asarray(inputs, dtype=np.float64)))
