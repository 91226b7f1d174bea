"""The paper's "Naive diff τ_eff" baseline (IV-B 1): the proposed score with a = 1, b = 0,

    score(t) = ‖τ̃_eff(t) − τ̂̃_eff(t)‖²,

on the low-pass filtered measured and simulated efforts. No training.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from twincd.detection.score import affine_score
from twincd.evaluation.methods import ScoringMethod
from twincd.prepare.prepared import PreparedLog
from twincd.types import FloatArray


class NaiveDiff(ScoringMethod):
    """‖τ̃ − τ̂̃‖² per sample (deterministic: no ``seed``, so evaluate runs it once)."""

    name = "naive-diff"
    unit = "sample"
    learns = False

    def fit(self, train: Sequence[PreparedLog]) -> NaiveDiff:
        return self

    def score(self, log: PreparedLog) -> FloatArray:
        dof = log.effort_f.shape[1]
        return affine_score(log.effort_f, log.twin_f, np.ones(dof), np.zeros(dof))
