"""μ + kσ of the score on collision-free logs (the paper's threshold), from mergeable sums; or
the lowest threshold that keeps false alarms within a budget per hour of those logs.

A false alarm is a maximal run of flags (DESIGN §6); on collision-free logs every run is one.
For the budget, each log counts its runs at every threshold of a fixed log-spaced grid in one
pass (a run starts at sample i for every threshold t with s[i−1] < t ≤ s[i]), so counts merge by
addition and memory stays flat; the threshold is then the lowest grid value above which no
threshold gives more alarms than the budget allows. σ of collision-free scores says little of
their rare excursions (the friction models' scores have heavy tails): a budget met on an hour of
validation data is what a CI gate or an operator can rely on.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twincd.calibration import Calibration, Threshold, clean_mask, clean_rows
from twincd.calibration.models import model_inputs
from twincd.defaults import DEFAULT_K_SIGMA
from twincd.errors import DataError, UsageError
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


# candidate thresholds of a false-alarm budget: 64 per decade (3.7 % apart) over any score
ALARM_GRID = np.logspace(-9.0, 12.0, 21 * 64 + 1)


@dataclass(frozen=True)
class AlarmCounts:
    """Mergeable: per threshold of ``ALARM_GRID`` the runs of scores at or above it, and the
    collision-free time judged (s)."""

    runs: NDArray[np.int64]
    seconds: float = 0.0

    @classmethod
    def zeros(cls) -> AlarmCounts:
        return cls(np.zeros(len(ALARM_GRID), dtype=np.int64))

    def __add__(self, other: AlarmCounts) -> AlarmCounts:
        return AlarmCounts(self.runs + other.runs, self.seconds + other.seconds)


class AlarmCounter:
    """Counts the runs of one log block by block: a run that goes on across blocks is counted
    once, a sample left out (labelled, at a filter edge) ends a run."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._last = -np.inf  # the previous sample's score (−∞: left out, or none yet)
        self._counts = AlarmCounts.zeros()

    def push(self, scores: FloatArray, usable: BoolArray) -> None:
        s = np.where(usable, np.asarray(scores, dtype=np.float64), -np.inf)
        if not len(s):
            return
        before = np.concatenate(([self._last], s[:-1]))
        self._last = float(s[-1])
        rising = usable & (s > before)
        # a run starts here for every threshold t with before < t ≤ s
        first = np.searchsorted(ALARM_GRID, before[rising], side="right")
        stop = np.searchsorted(ALARM_GRID, s[rising], side="right")
        size = len(ALARM_GRID) + 1
        steps = np.bincount(first, minlength=size) - np.bincount(stop, minlength=size)
        runs = self._counts.runs + np.cumsum(steps)[:-1]
        seconds = self._counts.seconds + float(np.count_nonzero(usable)) * self.period_s
        self._counts = AlarmCounts(runs, seconds)

    @property
    def counts(self) -> AlarmCounts:
        return self._counts


def check_threshold_settings(k_sigma: float, per_hour: float | None = None) -> None:
    """A finite k ≥ 0, and a finite budget ≥ 0 when one is given (checked before any work)."""
    if not (math.isfinite(k_sigma) and k_sigma >= 0):
        raise UsageError(
            f"k of the threshold μ + kσ must be a finite number ≥ 0, not {k_sigma}",
            "threshold",
            "give k such as 4 (the paper's)",
            option="sigma",
        )
    if per_hour is not None and not (math.isfinite(per_hour) and per_hour >= 0):
        raise UsageError(
            f"the false-alarm budget must be a finite number ≥ 0 per hour, not {per_hour}",
            "threshold",
            "give a budget such as 1 (per hour)",
            option="false_alarms_per_hour",
        )


def budget_threshold(
    counts: AlarmCounts, stats: ScoreStats, per_hour: float, logs: Sequence[str] = ()
) -> Threshold:
    """The lowest value of ``ALARM_GRID`` at or above μ, above which the logs' false alarms
    per hour never exceed ``per_hour``, as μ + kσ with its k and the alarms at that value."""
    check_threshold_settings(0.0, per_hour)
    mu = stats.mu  # no collision-free samples: a clear error here
    allowed = per_hour * counts.seconds / 3600.0
    over = np.flatnonzero(counts.runs > allowed + 1e-9)
    lowest = int(np.searchsorted(ALARM_GRID, mu, side="left"))  # never below μ (k ≥ 0)
    index = min(max(int(over[-1]) + 1 if len(over) else 0, lowest), len(ALARM_GRID) - 1)
    value = float(ALARM_GRID[index])
    sigma = stats.sigma
    k_sigma = (value - mu) / sigma if sigma > 0 else 0.0
    hours = counts.seconds / 3600.0
    needed = max(1.0, 1.0 / per_hour) if per_hour > 0 else 1.0
    if hours < needed and per_hour * hours < 1.0:
        log.warning(
            "the validation logs hold %.3g min of collision-free data: a budget of %g false "
            "alarm(s) per hour needs %.3g h or more of it to be shown; the threshold then sits "
            "above the highest score seen and may alarm more often on other logs",
            counts.seconds / 60.0,
            per_hour,
            needed,
        )
    return Threshold(
        k_sigma,
        mu,
        sigma,
        tuple(logs),
        stats.n,
        budget_per_hour=per_hour,
        false_alarms=int(counts.runs[index]),
        judged_s=counts.seconds,
    )


@dataclass(frozen=True)
class LogScores:
    """What one validation log contributes to a threshold (the per-log step)."""

    source: str
    stats: ScoreStats
    samples: int = 0  # every sample read (labelled ones too): what progress counts
    alarms: AlarmCounts | None = None


def score_log(path: str | Path, setup: Setup, calibration: Calibration) -> LogScores:
    """Stream one log into statistics of its calibrated score on collision-free samples, and
    its runs at every threshold of the false-alarm grid."""
    stats = ScoreStats()
    with setup.open(path) as stream:
        counter: AlarmCounter | None = None
        for frame in stream:
            counter = counter or AlarmCounter(stream.period_s)
            scores = calibration.model.scores(
                {
                    **frame,
                    "coulomb_eps": stream.coulomb_eps,
                    "regressor_mask": stream.regressor_mask,
                }
            )
            usable = clean_rows(frame.get("labels"), frame.n, frame.get("edge"))
            stats = stats + ScoreStats.from_scores(scores, usable)
            counter.push(scores, usable)
    alarms = None if counter is None else counter.counts
    return LogScores(str(path), stats, stream.samples, alarms)


def with_threshold(
    parts: Iterable[LogScores],
    calibration: Calibration,
    k_sigma: float = DEFAULT_K_SIGMA,
    false_alarms_per_hour: float | None = None,
) -> Calibration:
    """The calibration with μ + kσ from per-log statistics merged in any order; or, with
    ``false_alarms_per_hour``, with the lowest threshold that keeps within that budget."""
    parts = sorted(parts, key=lambda p: p.source)
    total = ScoreStats()
    alarms = AlarmCounts.zeros()
    for p in parts:
        total = total + p.stats
        if p.alarms is not None:
            alarms = alarms + p.alarms
    seen = [p.source for p in parts]
    reused = sorted(set(seen) & set(calibration.fit_logs))
    if reused:
        log.warning(
            "%d threshold log(s) were also used by fit (%s): μ and σ will be optimistic; "
            "use separate validation logs",
            len(reused),
            reused[0],
        )
    check_threshold_settings(k_sigma, false_alarms_per_hour)
    if false_alarms_per_hour is not None:
        threshold = budget_threshold(alarms, total, false_alarms_per_hour, seen)
        return calibration.with_threshold(threshold)
    return calibration.with_threshold(total.threshold(k_sigma, seen))


def threshold_calibration(
    paths: Iterable[str | Path],
    calibration: Calibration,
    setup: Setup,
    k_sigma: float = DEFAULT_K_SIGMA,
    false_alarms_per_hour: float | None = None,
) -> Calibration:
    """μ + kσ of the calibrated score on collision-free logs, each streamed (or the threshold
    of a false-alarm budget, see ``with_threshold``)."""
    parts = [score_log(p, setup, calibration) for p in paths]
    return with_threshold(parts, calibration, k_sigma, false_alarms_per_hour)


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
