"""What collision-free data scored: mergeable statistics of a score (``ScoreStats``: count,
mean, centred sum of squares and a histogram for the median and MAD) and, per band of a
calibration's score, with its excursions (``BandStats``), as ``threshold`` merges them and as a
calibration file keeps those of its fit's own logs (cross-fitted:
``twincd.calibration.crossfit``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.calibration.tail import LEVELS, MAX_PEAKS, Excursions
from twincd.defaults import DEFAULT_K_SIGMA
from twincd.errors import DataError
from twincd.signal.moments import Moments
from twincd.signal.stream import SegmentedStage
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.calibration.file import Threshold

# The robust estimator's histogram of scores: bins of ``HISTOGRAM_STEP`` from ``HISTOGRAM_LOW``
# (a depth statistic's z lies above −3); scores beyond count in the end bins, which moves the
# median and the MAD only once half the samples lie there. 80 kB per log, merged exactly.
HISTOGRAM_LOW, HISTOGRAM_STEP, HISTOGRAM_BINS = -10.0, 0.01, 10_000
MAD_TO_SIGMA = 1.4826  # σ of a normal distribution per median absolute deviation


@dataclass(frozen=True)
class ScoreStats:
    """Mergeable count, mean and centred sum of squares of scores (Chan et al.'s update, so
    merges are exact in any order), and their histogram: μ and σ (population), or the median
    and MAD, of everything merged."""

    n: int = 0
    mean: float = 0.0
    m2: float = 0.0  # Σ (s − mean)²
    histogram: IntArray | None = None  # counts per bin (None: no score yet)

    @classmethod
    def from_scores(cls, scores: FloatArray, mask: BoolArray | None = None) -> ScoreStats:
        x = np.asarray(scores, dtype=np.float64)
        if mask is not None:
            x = x[mask]
        x = x[np.isfinite(x)]  # a band not judged there (−∞: the fast band at a jump)
        if len(x) == 0:
            return cls()
        mean = float(x.mean())
        at = np.clip((x - HISTOGRAM_LOW) / HISTOGRAM_STEP, 0, HISTOGRAM_BINS - 1).astype(np.intp)
        histogram = np.bincount(at, minlength=HISTOGRAM_BINS).astype(np.int64)
        return cls(len(x), mean, float(((x - mean) ** 2).sum()), histogram)

    def __add__(self, other: ScoreStats) -> ScoreStats:
        if other.n == 0:
            return self
        if self.n == 0:
            return other
        histogram = None
        if self.histogram is not None and other.histogram is not None:
            histogram = self.histogram + other.histogram
        mine, theirs = (Moments(s.n, np.float64(s.mean), np.float64(s.m2)) for s in (self, other))
        merged = mine + theirs
        return ScoreStats(int(merged.n), float(merged.mean), float(merged.m2), histogram)

    @property
    def mu(self) -> float:
        self._check()
        return self.mean

    @property
    def sigma(self) -> float:
        self._check()
        return float(np.sqrt(self.m2 / self.n))

    def robust(self) -> tuple[float, float]:
        """(median, 1.4826 × median absolute deviation), to the histogram's step."""
        self._check()
        if self.histogram is None:
            raise DataError(
                "these score statistics carry no histogram for a robust threshold",
                "threshold",
                "score the logs with ScoreStats.from_scores",
            )
        centres = HISTOGRAM_LOW + HISTOGRAM_STEP * (
            np.arange(HISTOGRAM_BINS, dtype=np.float64) + 0.5
        )
        median = _weighted_median(centres, self.histogram)
        mad = _weighted_median(np.abs(centres - median, dtype=np.float64), self.histogram)
        return median, MAD_TO_SIGMA * mad

    def _check(self) -> None:
        if self.n == 0:
            raise DataError(
                "no collision-free samples to set a threshold",
                "threshold",
                "give validation logs without collisions (or with labels)",
            )

    def threshold(self, k_sigma: float = DEFAULT_K_SIGMA, logs: Sequence[str] = ()) -> Threshold:
        """μ + kσ with the mean and standard deviation (the paper's)."""
        from twincd.calibration.file import Threshold

        return Threshold(k_sigma, self.mu, self.sigma, tuple(logs), self.n)


def _weighted_median(values: FloatArray, counts: IntArray) -> float:
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(counts[order])
    at = int(np.searchsorted(cumulative, cumulative[-1] / 2.0))
    return float(values[order][at])


@dataclass(frozen=True)
class BandStats:
    """One band's score on collision-free data: its statistics and its excursions (mergeable,
    in any order)."""

    stats: ScoreStats = field(default_factory=ScoreStats)
    excursions: Excursions = field(default_factory=Excursions)

    def __add__(self, other: BandStats) -> BandStats:
        return BandStats(self.stats + other.stats, self.excursions + other.excursions)

    def to_dict(self) -> dict[str, Any]:
        """For a calibration file: counts and sums, the histogram's non-empty bins, and per
        level of ``twincd.calibration.tail.LEVELS`` its excursions and their peaks (to 7
        significant digits)."""
        st, ex = self.stats, self.excursions
        histogram = [] if st.histogram is None else np.flatnonzero(st.histogram).tolist()
        return {
            "n": st.n,
            "mean": st.mean,
            "m2": st.m2,
            "histogram": [[i, int(st.histogram[i])] for i in histogram]
            if st.histogram is not None
            else None,
            "clean_s": ex.seconds,
            "levels": [
                [i, count, None if peaks is None else [float(f"{p:.7g}") for p in peaks]]
                for i, (count, peaks) in enumerate(zip(ex.counts, ex.peaks, strict=True))
                if count
            ],
        }


def read_band_stats(d: Any, field_name: str, where: str) -> BandStats:
    """``BandStats.to_dict``'s block read back, every number validated."""
    from twincd.calibration.values import finite_number

    n = int(finite_number(d["n"], f"{field_name}.n", where))
    histogram = None
    if d.get("histogram") is not None:
        histogram = np.zeros(HISTOGRAM_BINS, dtype=np.int64)
        for i, count in d["histogram"]:
            histogram[int(i)] = int(count)
    stats = ScoreStats(
        n,
        finite_number(d["mean"], f"{field_name}.mean", where),
        finite_number(d["m2"], f"{field_name}.m2", where),
        histogram,
    )
    counts = [0] * len(LEVELS)
    peaks: list[tuple[float, ...] | None] = [()] * len(LEVELS)
    for i, count, kept in d["levels"]:
        counts[int(i)] = int(count)
        peaks[int(i)] = (
            None
            if kept is None
            else tuple(finite_number(p, f"{field_name}.levels", where) for p in kept)
        )
        if kept is not None and len(kept) > MAX_PEAKS:
            raise ValueError(f"{field_name}.levels keeps more than {MAX_PEAKS} peaks")
    seconds = finite_number(d["clean_s"], f"{field_name}.clean_s", where)
    excursions = Excursions(tuple(counts), tuple(peaks), round(seconds * 1e9))
    return BandStats(stats, excursions)


def band_stats(
    scores: FloatArray, usable: BoolArray, period_s: float, stamps: Sequence[int] | None = None
) -> BandStats:
    """One log's (or block's) ``BandStats`` of ``scores`` where ``usable``."""
    from twincd.calibration.tail import ExcursionCounter

    counter = ExcursionCounter(period_s)
    counter.push(scores, usable)
    return BandStats(ScoreStats.from_scores(scores, usable), counter.excursions)


# a person's switch marks a push late and lets go early: a push's effect on the effort starts
# before its labelled span and ends after it (the real arm's highest clean excursions lie within
# 0.01–0.13 s of a labelled push). Statistics of collision-free data leave out this much either
# side of every labelled sample; events and their false alarms keep evaluate's ± 200 ms.
LABEL_MARGIN_S = 0.5


class LabelMargin(SegmentedStage):
    """1.0 for samples within ``LABEL_MARGIN_S`` of a labelled one (the labels pushed: 1.0 where
    labelled), else 0.0; a sample waits for the margin after it (segments cut at gaps as every
    stage cuts)."""

    def __init__(self, period_s: float, margin_s: float = LABEL_MARGIN_S) -> None:
        super().__init__(period_s)
        self.reach = max(0, round(margin_s / self.period_s))
        self.lookahead = self.reach
        self._labels = np.zeros(0, dtype=bool)  # from the oldest still needed
        self._base = 0  # segment index of ``_labels[0]``
        self._next = 0
        self._n = 0

    def _extend(self, t: IntArray, y: FloatArray) -> FloatArray:
        self._labels = np.concatenate((self._labels, y[:, 0] > 0))
        self._n += len(t)
        return self._emit(self._n - self.reach)

    def _end_segment(self) -> FloatArray:
        out = self._emit(self._n)
        self._labels, self._base, self._next, self._n = np.zeros(0, dtype=bool), 0, 0, 0
        return out

    def _emit(self, stop: int) -> FloatArray:
        index = np.arange(self._next, max(stop, self._next))
        if not len(index):
            return np.zeros((0, 1))
        at = np.flatnonzero(self._labels) + self._base
        lo = np.searchsorted(at, index - self.reach, side="left")
        hi = np.searchsorted(at, index + self.reach, side="right")
        near = (hi > lo).astype(np.float64)[:, None]
        self._next = int(index[-1]) + 1
        keep = max(self._base, self._next - self.reach)
        self._labels = self._labels[keep - self._base :]
        self._base = keep
        return near


def near_labels(labels: BoolArray | None, period_s: float) -> BoolArray | None:
    """``LabelMargin`` of a whole log's labels (None: unlabelled)."""
    if labels is None:
        return None
    stage = LabelMargin(period_s)
    stamps = np.arange(len(labels), dtype=np.int64) * round(period_s * 1e9)
    values = np.asarray(labels, dtype=np.float64)
    out = np.concatenate((stage.push(stamps, values), stage.finish()))
    near: BoolArray = out.reshape(-1) > 0
    return near
