"""Mergeable moments: the count, means and centred second moments of some columns, merged
exactly in any order and any split by Chan et al.'s pairwise update (what every statistics class
of a fit, a threshold or a motion check sums one log or block at a time)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeAlias

import numpy as np

from twincd.types import FloatArray, IntArray

Count: TypeAlias = int | IntArray  # one count, or one per cell


@dataclass(frozen=True)
class Moments:
    """Count ``n``, means ``mean`` (..., K) and centred second moments ``m2`` of K columns:
    their cross-products (..., K, K), or each column's own sum of squared deviations (..., K).

    ``n`` is one count, or one per cell (an array of the leading shape): each cell then merges
    on its own and an empty cell merges as nothing. ``+`` is exact (up to rounding) and does
    not depend on the order or the split of the samples."""

    n: Count
    mean: FloatArray
    m2: FloatArray

    @property
    def cross(self) -> bool:
        """``m2`` holds cross-products (..., K, K), not one sum per column."""
        return bool(np.ndim(self.m2) == np.ndim(self.mean) + 1)

    def __add__(self, other: Moments) -> Moments:
        if isinstance(self.n, int) and isinstance(other.n, int):
            if self.n == 0:
                return other
            if other.n == 0:
                return self
            n: Count = self.n + other.n
            share, weight = other.n / n, self.n * other.n / n
            return self._merged(other, n, share, weight)
        n = np.asarray(self.n) + np.asarray(other.n)
        total = np.maximum(n, 1)
        share = (other.n / total)[..., None]
        weight = (self.n * other.n / total)[..., None]
        return self._merged(other, n, share, weight[..., None] if self.cross else weight)

    def _merged(
        self, other: Moments, n: Count, share: float | FloatArray, weight: float | FloatArray
    ) -> Moments:
        delta = other.mean - self.mean
        spread = delta[..., :, None] * delta[..., None, :] if self.cross else delta * delta
        mean: FloatArray = self.mean + delta * share
        m2: FloatArray = self.m2 + other.m2 + spread * weight
        return Moments(n, mean, m2)
