"""μ + kσ of the score on collision-free logs (the paper's threshold), from mergeable sums."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twincd.calibration import Calibration, Threshold, clean_mask, clean_rows
from twincd.calibration.models import model_inputs
from twincd.defaults import DEFAULT_K_SIGMA
from twincd.errors import DataError
from twincd.pipeline import PreparedLog, Setup

log = logging.getLogger("twincd")

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class ScoreStats:
    """Mergeable count, mean and centred sum of squares of scores (Chan et al.'s update, so
    merges are exact in any order); μ and σ (population) of everything merged."""

    n: int = 0
    mean: float = 0.0
    m2: float = 0.0  # Σ (s − mean)²

    @classmethod
    def from_scores(cls, scores: FloatArray, mask: BoolArray | None = None) -> ScoreStats:
        x = np.asarray(scores, dtype=np.float64)
        if mask is not None:
            x = x[mask]
        if len(x) == 0:
            return cls()
        mean = float(x.mean())
        return cls(len(x), mean, float(((x - mean) ** 2).sum()))

    def __add__(self, other: ScoreStats) -> ScoreStats:
        if other.n == 0:
            return self
        if self.n == 0:
            return other
        n = self.n + other.n
        delta = other.mean - self.mean
        return ScoreStats(
            n,
            self.mean + delta * other.n / n,
            self.m2 + other.m2 + delta * delta * self.n * other.n / n,
        )

    @property
    def mu(self) -> float:
        self._check()
        return self.mean

    @property
    def sigma(self) -> float:
        self._check()
        return float(np.sqrt(self.m2 / self.n))

    def _check(self) -> None:
        if self.n == 0:
            raise DataError(
                "no collision-free samples to set a threshold",
                "threshold",
                "give validation logs without collisions (or with labels)",
            )

    def threshold(self, k_sigma: float = DEFAULT_K_SIGMA, logs: Sequence[str] = ()) -> Threshold:
        return Threshold(k_sigma, self.mu, self.sigma, tuple(logs), self.n)


@dataclass(frozen=True)
class LogScores:
    """What one validation log contributes to a threshold (the per-log step)."""

    source: str
    stats: ScoreStats
    samples: int = 0  # every sample read (labelled ones too): what progress counts


def score_log(path: str | Path, setup: Setup, calibration: Calibration) -> LogScores:
    """Stream one log into statistics of its calibrated score on collision-free samples."""
    stats = ScoreStats()
    with setup.open(path) as stream:
        for frame in stream:
            scores = calibration.model.scores({**frame, "coulomb_eps": stream.coulomb_eps})
            usable = clean_rows(frame.get("labels"), frame.n, frame.get("edge"))
            stats = stats + ScoreStats.from_scores(scores, usable)
    return LogScores(str(path), stats, stream.samples)


def with_threshold(
    parts: Iterable[LogScores], calibration: Calibration, k_sigma: float = DEFAULT_K_SIGMA
) -> Calibration:
    """The calibration with μ + kσ from per-log statistics merged in any order."""
    parts = sorted(parts, key=lambda p: p.source)
    total = ScoreStats()
    for p in parts:
        total = total + p.stats
    seen = [p.source for p in parts]
    reused = sorted(set(seen) & set(calibration.fit_logs))
    if reused:
        log.warning(
            "%d threshold log(s) were also used by fit (%s): μ and σ will be optimistic; "
            "use separate validation logs",
            len(reused),
            reused[0],
        )
    return calibration.with_threshold(total.threshold(k_sigma, seen))


def threshold_calibration(
    paths: Iterable[str | Path],
    calibration: Calibration,
    setup: Setup,
    k_sigma: float = DEFAULT_K_SIGMA,
) -> Calibration:
    """μ + kσ of the calibrated score on collision-free logs, each streamed."""
    return with_threshold([score_log(p, setup, calibration) for p in paths], calibration, k_sigma)


def calibrate_threshold(
    logs: Iterable[PreparedLog], calibration: Calibration, k_sigma: float = DEFAULT_K_SIGMA
) -> Calibration:
    """The same from logs already prepared in memory."""
    parts = (
        LogScores(
            lg.source,
            ScoreStats.from_scores(
                calibration.model.scores(model_inputs(lg)),
                clean_mask(lg),
            ),
        )
        for lg in logs
    )
    return with_threshold(parts, calibration, k_sigma)
