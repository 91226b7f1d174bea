"""μ + kσ of the score on collision-free logs (the paper's threshold), from mergeable sums."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from twincd.calibration import Calibration, Threshold, clean_mask
from twincd.detection.score import affine_score
from twincd.errors import DataError
from twincd.pipeline import PreparedLog

log = logging.getLogger("twincd")

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

DEFAULT_K_SIGMA = 4.0  # the paper's μ + 4σ


@dataclass(frozen=True)
class ScoreStats:
    """Mergeable n, Σs, Σs² of scores; μ and σ (population) of everything merged."""

    n: int = 0
    s: float = 0.0
    ss: float = 0.0

    @classmethod
    def from_scores(cls, scores: FloatArray, mask: BoolArray | None = None) -> ScoreStats:
        x = np.asarray(scores, dtype=np.float64)
        if mask is not None:
            x = x[mask]
        return cls(len(x), float(x.sum()), float((x * x).sum()))

    def __add__(self, other: ScoreStats) -> ScoreStats:
        return ScoreStats(self.n + other.n, self.s + other.s, self.ss + other.ss)

    @property
    def mu(self) -> float:
        self._check()
        return self.s / self.n

    @property
    def sigma(self) -> float:
        self._check()
        return float(np.sqrt(max(self.ss / self.n - self.mu**2, 0.0)))

    def _check(self) -> None:
        if self.n == 0:
            raise DataError(
                "no collision-free samples to set a threshold",
                "threshold",
                "give validation logs without collisions (or with labels)",
            )

    def threshold(self, k_sigma: float = DEFAULT_K_SIGMA, logs: Sequence[str] = ()) -> Threshold:
        return Threshold(k_sigma, self.mu, self.sigma, tuple(logs), self.n)


def score_stats(scores: Iterable[tuple[FloatArray, BoolArray | None]]) -> ScoreStats:
    """Merged statistics of (scores, collision-free mask) per log."""
    total = ScoreStats()
    for s, mask in scores:
        total = total + ScoreStats.from_scores(s, mask)
    return total


def threshold_stats(logs: Iterable[PreparedLog], calibration: Calibration) -> ScoreStats:
    """μ/σ statistics of the calibrated score over the collision-free samples of ``logs``."""
    return score_stats(
        (affine_score(lg.effort_f, lg.sim_effort_f, calibration.a, calibration.b), clean_mask(lg))
        for lg in logs
    )


def calibrate_threshold(
    logs: Iterable[PreparedLog], calibration: Calibration, k_sigma: float = DEFAULT_K_SIGMA
) -> Calibration:
    """The calibration with μ + kσ of its score on collision-free ``logs`` (streamed)."""
    seen: list[str] = []

    def stream() -> Iterator[PreparedLog]:
        for lg in logs:
            seen.append(lg.source)
            yield lg

    stats = threshold_stats(stream(), calibration)
    reused = sorted(set(seen) & set(calibration.fit_logs))
    if reused:
        log.warning(
            "%d threshold log(s) were also used by fit (%s): μ and σ will be optimistic; "
            "use separate validation logs",
            len(reused),
            reused[0],
        )
    return calibration.with_threshold(stats.threshold(k_sigma, seen))
