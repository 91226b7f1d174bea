"""The paper's regression τ̃ ≈ a⊙τ̂̃ + b (eq. 3–4): its mergeable statistics and solution.

Fitting is split into a pure per-log step (``AffineStats.from_arrays``: sufficient statistics of
one log or block) and a merge (``+``), so memory stays flat for any number of logs and the
per-log work can run in other processes or on a cluster.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.calibration.excitation import PRIOR, affordable, conditioning, gain_held
from twincd.errors import DataError
from twincd.signal.moments import Moments
from twincd.types import BoolArray, FloatArray

if TYPE_CHECKING:
    from twincd.prepare.prepared import PreparedLog

log = logging.getLogger("twincd")


# a joint whose twin effort varies less than this fraction of the measured effort's spread gives
# a slope that mostly amplifies noise (the paper's joint 7: a = 21.7)
CONDITION_RATIO = 0.1
# a fit leaves out samples whose filtered values are noisier than this many times the middle's
# (the first and last ≈ 0.15 s of a segment under the critically damped 1.5 Hz filter)
FIT_EDGE_FACTOR = 1.1


def clean_rows(labels: BoolArray | None, n: int) -> BoolArray:
    """Rows of collision-free samples: all, or those labelled collision-free (what a threshold
    judges: every sample is judged, its ends with their own noise, ``twincd.signal.edges``)."""
    return np.ones(n, dtype=bool) if labels is None else ~np.asarray(labels, dtype=bool)


def fit_rows(labels: BoolArray | None, n: int, edge_factor: Any = None) -> BoolArray:
    """Rows a fit sums: the collision-free ones (``clean_rows``) whose filtered values are as
    good as the segment's middle (edge factor at most ``FIT_EDGE_FACTOR``): a fit weighs every
    sample alike, so the noisier estimates next to a segment's ends are left to scoring."""
    rows = clean_rows(labels, n)
    if edge_factor is not None:
        factor = np.asarray(edge_factor, dtype=np.float64).reshape(n, -1)
        rows &= factor.max(axis=1) <= FIT_EDGE_FACTOR
    return rows


def clean_mask(log_: PreparedLog) -> BoolArray:
    """``clean_rows`` of a whole prepared log."""
    return clean_rows(log_.labels, len(log_))


def fit_mask(log_: PreparedLog) -> BoolArray:
    """``fit_rows`` of a whole prepared log."""
    return fit_rows(log_.labels, len(log_), log_.edge_factor)


def same_joints(mine: int, theirs: int) -> None:
    """Statistics of logs with different joint counts do not merge."""
    if mine != theirs:
        raise DataError(
            "logs with different joint counts cannot be fitted together",
            f"{mine} vs {theirs} joints",
            "fit logs of one robot",
        )


@dataclass(frozen=True)
class AffineStats:
    """Mergeable sufficient statistics of a per-joint regression y ≈ a·x + b.

    Means and *centred* sums of squares and products, merged with Chan et al.'s pairwise
    update: raw Σx² − (Σx)²/n would cancel the signal of efforts with large constant offsets.
    """

    n: int
    mean_x: FloatArray
    mean_y: FloatArray
    cxx: FloatArray  # Σ (x − x̄)²
    cyy: FloatArray  # Σ (y − ȳ)²
    cxy: FloatArray  # Σ (x − x̄)(y − ȳ)

    @classmethod
    def zeros(cls, joints: int) -> AffineStats:
        z = np.zeros(joints)
        return cls(0, z, z, z, z, z)

    @classmethod
    def from_arrays(
        cls, x: FloatArray, y: FloatArray, mask: BoolArray | None = None
    ) -> AffineStats:
        """Statistics of (N, D) arrays x = τ̂̃ and y = τ̃, rows where ``mask`` holds."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if mask is not None:
            x, y = x[mask], y[mask]
        if len(x) == 0:
            return cls.zeros(x.shape[1] if x.ndim == 2 else 0)
        mx, my = x.mean(axis=0), y.mean(axis=0)
        dx, dy = x - mx, y - my
        return cls(
            n=len(x),
            mean_x=mx,
            mean_y=my,
            cxx=(dx * dx).sum(axis=0),
            cyy=(dy * dy).sum(axis=0),
            cxy=(dx * dy).sum(axis=0),
        )

    @classmethod
    def from_weighted(cls, x: FloatArray, y: FloatArray, weight: Any) -> AffineStats:
        """``from_arrays`` of rows that each stand for ``weight`` samples (a grid's nodes)."""
        rows = np.flatnonzero(np.asarray(weight))
        w = np.asarray(weight, dtype=np.float64)[rows, None]
        x = np.asarray(x, dtype=np.float64)[rows]
        y = np.asarray(y, dtype=np.float64)[rows]
        if len(rows) == 0:
            return cls.zeros(x.shape[1] if x.ndim == 2 else 0)
        n = float(w.sum())
        mx, my = (w * x).sum(axis=0) / n, (w * y).sum(axis=0) / n
        dx, dy = x - mx, y - my
        return cls(
            n=int(n),
            mean_x=mx,
            mean_y=my,
            cxx=(w * dx * dx).sum(axis=0),
            cyy=(w * dy * dy).sum(axis=0),
            cxy=(w * dx * dy).sum(axis=0),
        )

    def __add__(self, other: AffineStats) -> AffineStats:
        if self.n == 0:
            return other
        if other.n == 0:
            return self
        same_joints(self.mean_x.shape[0], other.mean_x.shape[0])
        merged = self.moments + other.moments
        mean, m2 = merged.mean, merged.m2
        return AffineStats(
            int(merged.n), mean[:, 0], mean[:, 1], m2[:, 0, 0], m2[:, 1, 1], m2[:, 0, 1]
        )

    @property
    def moments(self) -> Moments:
        """The columns [τ̂̃, τ̃] of each joint as ``Moments``: means (D, 2), cross-products
        (D, 2, 2)."""
        cross = np.stack(
            [np.stack([self.cxx, self.cxy], axis=-1), np.stack([self.cxy, self.cyy], axis=-1)],
            axis=-2,
        )
        return Moments(self.n, np.stack([self.mean_x, self.mean_y], axis=-1), cross)

    @property
    def var_x(self) -> FloatArray:
        return self.cxx / self.n

    @property
    def var_y(self) -> FloatArray:
        return self.cyy / self.n


def require_samples(n: int, minimum: int) -> None:
    if n < minimum:
        raise DataError(
            "too few collision-free samples to fit",
            f"{n} sample(s)",
            "give longer logs, or logs with collision-free parts",
        )


def r_squared(sse: FloatArray, total: FloatArray) -> FloatArray:
    """1 − SSE/SST per joint; 1 where the measured effort does not vary at all."""
    out: FloatArray = np.where(total > 0, 1.0 - sse / np.where(total > 0, total, 1.0), 1.0)
    return out


@dataclass(frozen=True)
class AffineSolution:
    a: FloatArray
    b: FloatArray
    r2: FloatArray
    rmse: FloatArray
    ill_conditioned: BoolArray
    # joints whose twin effort stays at one level, so that a and b cannot be told apart, or
    # whose logs hold too few independent samples for a and b: a is held at 1 there
    # (``twincd.calibration.excitation``)
    held: BoolArray
    gain_share: FloatArray  # each joint's twin effort's spread over its RMS (``gain_share``)
    scarce: BoolArray  # of ``held``, those held for want of independent samples


def gain_share(stats: AffineStats) -> FloatArray:
    """Each joint's twin effort's part not reproduced by the intercept, at unit RMS: its spread
    over its RMS (``twincd.calibration.excitation.conditioning`` of the one column)."""
    out: FloatArray = conditioning(stats.n, stats.mean_x[:, None], stats.cxx[:, None, None])[:, 0]
    return out


def solve(stats: AffineStats, independent: float | None = None) -> AffineSolution:
    """Least squares per joint from merged statistics (closed form of eq. 3); where the twin's
    effort stays at one level (``gain_share``), or the ``independent`` samples are too few
    for a and b (``excitation.affordable``), a is held at 1 and b fits what it leaves."""
    require_samples(stats.n, 2)
    n = stats.n
    cxx, cyy, cxy = stats.cxx, stats.cyy, stats.cxy
    degenerate = cxx <= 1e-12 * np.maximum(cyy, 1e-300)
    a = np.where(degenerate, 0.0, cxy / np.where(degenerate, 1.0, cxx))
    sse = np.maximum(cyy - a * cxy, 0.0)
    share = gain_share(stats)
    held = gain_held(share, np.sqrt(cxx / n), np.sqrt(sse / n))
    scarce = ~held & (affordable(independent) < 2)
    held |= scarce
    if held.any():
        a = np.where(held, PRIOR["a"], a)
        sse = np.where(held, np.maximum(cyy - 2.0 * a * cxy + a * a * cxx, 0.0), sse)
    b = stats.mean_y - a * stats.mean_x
    r2 = r_squared(sse, cyy)
    rmse = np.sqrt(sse / n)
    ill = degenerate | (np.sqrt(cxx) < CONDITION_RATIO * np.sqrt(cyy))
    return AffineSolution(a, b, r2, rmse, ill & ~held, held, share, scarce)


def warn_ill_conditioned(
    names: Sequence[str] | None, stats: AffineStats, ill_conditioned: BoolArray, a: FloatArray
) -> None:
    """One warning per joint whose slope ``a`` mostly amplifies noise (``CONDITION_RATIO``)."""
    names = list(names or [f"#{i}" for i in range(len(a))])
    for i in np.flatnonzero(ill_conditioned):
        log.warning(
            "joint %s is badly conditioned: its twin effort barely varies "
            "(std %.3g vs measured %.3g), so a = %.3g is unreliable",
            names[i],
            math.sqrt(float(stats.var_x[i])),
            math.sqrt(float(stats.var_y[i])),
            float(a[i]),
        )
