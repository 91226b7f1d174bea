"""The paper's score (eq. 5): score(t) = ‖τ̃(t) − (a⊙τ̂̃(t) + b)‖², as pure array functions
that the baselines reuse (naive-diff is a = 1, b = 0)."""

from __future__ import annotations

import numpy as np

from twincd.types import FloatArray


def residual(
    effort_f: FloatArray, sim_effort_f: FloatArray, a: FloatArray, b: FloatArray
) -> FloatArray:
    """τ̃ − (a⊙τ̂̃ + b), (N, D)."""
    out: FloatArray = np.asarray(effort_f) - (np.asarray(a) * np.asarray(sim_effort_f) + b)
    return out


def affine_score(
    effort_f: FloatArray, sim_effort_f: FloatArray, a: FloatArray, b: FloatArray
) -> FloatArray:
    """score(t) = ‖τ̃(t) − (a⊙τ̂̃(t) + b)‖² per sample (eq. 5), (N,)."""
    r = residual(effort_f, sim_effort_f, a, b)
    out: FloatArray = np.einsum("ij,ij->i", r, r)
    return out
