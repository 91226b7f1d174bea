"""The tail of a score from its excursions: peaks over a threshold, a generalised Pareto fit.

A false-alarm budget per hour cannot be counted on the minutes of clean data a user has; it can
be extrapolated from how the score's excursions are distributed (peaks over threshold, Coles
2001, ch. 4). The score of each log is declustered into excursions above every level of a fixed
geometric grid (a run of samples at or above the level that ends once the score has stayed
below it for ``DECLUSTER_GAP_S``), keeping each excursion's peak. Peaks are kept per level only
while a level has at most ``MAX_PEAKS`` of them, so what a log contributes is a few numbers per
level whatever its length, and merging logs (or blocks of one log) is exact in any order.

From the merged excursions a level u is chosen (the highest with ``TARGET_PEAKS`` peaks or
more), a generalised Pareto distribution (shape ξ, scale β) is fitted to the peaks' excesses
over u by maximum likelihood, and with λ the excursions per hour of clean time the threshold is
the x with λ·P(peak > x) = budget: x = u + β/ξ·((λ/budget)^ξ − 1). Its uncertainty is the
profile-likelihood interval of x (λ taken as known). With fewer than ``MIN_PEAKS`` peaks the
tail is taken as exponential (ξ = 0: one parameter, an exact χ² interval), and said.

The depth statistic (the default models' score) gets its own rule, ``fit_bulk_tail``: minutes of
clean data hold too few high peaks to measure a tail, so the rate of excursions is counted in
the score's bulk (at μ + 2σ, median and MAD) and carried up by an exponential tail whose scale
is set, until the data can measure it, from the score's median by what fresh clean logs of
many synthetic plants showed (``BULK_TAIL_SCALE``; studies/choose_budget.py). Once the clean
data hold ``TARGET_PEAKS`` excursions above μ + 3σ the tail is measured there instead
(``fit_tail``), and the threshold is said to be firm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from twincd.types import BoolArray, FloatArray

# levels u: 16 per decade over any score (15 % apart)
LEVELS = np.logspace(-9.0, 12.0, 21 * 16 + 1)
DECLUSTER_GAP_S = 0.2  # an excursion ends after this long below its level
MAX_PEAKS = 400  # a level with more excursions in one log (or merged) keeps no peaks
TARGET_PEAKS = 50  # u: the highest level with at least this many peaks
MIN_PEAKS = 10  # fewer peaks: the exponential tail instead of the GPD fit
CONFIDENCE = 0.90  # of the threshold's interval
# "rice-gaussian": Rice's formula for a smooth Gaussian score, the depth statistic's rule until it
# proved optimistic on fresh clean logs; files that record it keep loading
TAIL_METHODS = ("pot-gpd", "pot-exponential", "bulk-exponential", "rice-gaussian")
# bulk-exponential (``fit_bulk_tail``): the excursions' rate is counted at μ + BULK_LEVEL_SIGMA·σ
# and carried to the budget by an exponential tail of scale β = (s₀ + s₁·max(μ − μ₀, 0))·σ, with
# (s₀, s₁) = BULK_TAIL_SCALE and μ₀ the median the score would have if the residual were its
# noise alone. Chosen in studies/choose_budget.py: calibrations set from 1–3 min of clean
# synthetic data, each judged on fresh clean logs of its plant (an hour at 100 Hz, 20 min at
# 1 kHz). Their tails fall about sevenfold per σ, far slower than a Gaussian's exp(−z²/2), and
# the more slowly the further μ is above μ₀: a model that fits fresh motion less well than its
# training data (a residual above its noise scale) also strays further, more often. With s₀
# for the noise and s₁ for the misfit the budget held on the calibrations at both rates while
# the real arm (μ below μ₀) kept its pushes and their delay; one scale for all either broke
# the budget or lost pushes. s₀ was 0.35 until the noise scales were cross-fitted (each fit log
# scored by a model fitted without it) and the fit's own clean data joined the threshold's: the
# clean median then sits at μ₀, the misfit term vanishes, and 0.35 kept the budget for 15 of
# 30 calibrations at 100 Hz (162 events in 30 h). `choose_budget.py scales` over s₀ = 0.35–0.7:
# 0.65 is the least that kept it for all 30 (11 events in 30 h) and for 10 of 10 at 1 kHz, then
# kept it on the confirmation seeds (30 of 30, 13 events in 30 h; 10 of 10 at 1 kHz, none).
BULK_LEVEL_SIGMA = 2.0
BULK_TAIL_SCALE = (0.65, 0.8)
# μ − μ₀ the study covered (0.2–0.8): beyond it the scale is held at its end, and said
MISFIT_STUDIED = 1.0
# the tail is measured, not assumed, once the clean data hold TARGET_PEAKS excursions above this
FIRM_LEVEL_SIGMA = 3.0
# the GPD shapes ξ fitted: ξ ≥ 0, since a score that sums squared residuals has an exponential
# tail or a heavier one; a bounded tail (ξ < 0) fitted to a few minutes' peaks put the threshold
# below what an hour reaches (studies/choose_threshold.py)
SHAPES = (0.0, 1.0)


@dataclass(frozen=True)
class Excursions:
    """Mergeable: per level of ``LEVELS`` the number of excursions and their peaks (sorted;
    ``None`` once a level had more than ``MAX_PEAKS``), and the clean time judged (integer ns:
    sums in any grouping are equal)."""

    counts: tuple[int, ...] = field(default_factory=lambda: (0,) * len(LEVELS))
    peaks: tuple[tuple[float, ...] | None, ...] = field(default_factory=lambda: ((),) * len(LEVELS))
    clean_ns: int = 0

    @property
    def seconds(self) -> float:
        return self.clean_ns / 1e9

    def __add__(self, other: Excursions) -> Excursions:
        counts = tuple(a + b for a, b in zip(self.counts, other.counts, strict=True))
        peaks = tuple(
            _merge_peaks(a, b, n) for a, b, n in zip(self.peaks, other.peaks, counts, strict=True)
        )
        return Excursions(counts, peaks, self.clean_ns + other.clean_ns)

    def level_for_fit(self, lowest: float = -math.inf) -> int | None:
        """The index of u: the highest level with ``TARGET_PEAKS`` peaks or more (peaks kept),
        else the level with the most peaks kept (the higher on a tie); None without peaks.
        Only levels at or above the one with the most excursions are the tail's (below it,
        the score is above the level most of the time: a few long excursions, not a tail),
        and at or above ``lowest``."""
        mode = max(range(len(self.counts)), key=lambda i: (self.counts[i], i))
        start = max(mode, int(np.searchsorted(LEVELS, lowest, side="left")))
        kept = [i for i, p in enumerate(self.peaks) if p and i >= start]
        if not kept:
            return None
        enough = [i for i in kept if len(self.peaks[i] or ()) >= TARGET_PEAKS]
        if enough:
            return max(enough)
        return max(kept, key=lambda i: (len(self.peaks[i] or ()), i))


def _merge_peaks(
    a: tuple[float, ...] | None, b: tuple[float, ...] | None, count: int
) -> tuple[float, ...] | None:
    if a is None or b is None or count > MAX_PEAKS:
        return None
    return tuple(sorted(a + b))


class ExcursionCounter:
    """Excursions of one log, block by block: an excursion that goes on across blocks (or
    across a gap shorter than ``DECLUSTER_GAP_S``) is one; a sample left out (labelled, at a
    filter edge) is below every level. State: per level one open excursion."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.gap = max(1, round(DECLUSTER_GAP_S / period_s))  # samples below that end one
        n = len(LEVELS)
        self._index = 0  # global index of the next sample
        self._last_above = np.full(n, -(10**18), dtype=np.int64)  # last sample ≥ level
        self._open_peak = np.full(n, -np.inf)  # peak of the open excursion (−∞: none)
        self._counts = np.zeros(n, dtype=np.int64)
        self._peaks: list[list[float] | None] = [[] for _ in range(n)]
        self._usable = 0  # clean samples judged

    def push(self, scores: FloatArray, usable: BoolArray) -> None:
        s = np.where(usable, np.asarray(scores, dtype=np.float64), -np.inf)
        self._usable += int(np.count_nonzero(usable))
        finite = np.isfinite(s)
        if finite.any():
            # levels at or below every usable score share their excursions (split only by
            # left-out samples): segment those once; each level above segments its own
            shared = self._segments(np.flatnonzero(finite), s[finite])
            bottom = int(np.searchsorted(LEVELS, s[finite].min(), side="right"))
            top = int(np.searchsorted(LEVELS, s[finite].max(), side="right"))
            for j in range(top):
                if self._peaks[j] is None:
                    continue
                if j < bottom:
                    self._advance(j, *shared)
                else:
                    above = np.flatnonzero(s >= LEVELS[j])
                    self._advance(j, *self._segments(above, s[above]))
        self._index += len(s)

    def _segments(self, at: NDArray[np.int64], values: FloatArray) -> tuple[int, int, FloatArray]:
        """Samples above a level (block indices, scores) as excursions within the block: the
        first and last global index, and each excursion's peak."""
        starts = np.concatenate(([0], np.flatnonzero(np.diff(at) > self.gap) + 1))
        peaks = np.maximum.reduceat(values, starts)
        return self._index + int(at[0]), self._index + int(at[-1]), peaks

    def _advance(self, j: int, first: int, last: int, peaks: FloatArray) -> None:
        """Level j's state after a block whose excursions above it are ``peaks``."""
        open_peak = float(self._open_peak[j])
        found = [float(p) for p in peaks]
        closed: list[float] = []
        if first - self._last_above[j] > self.gap:  # the open one ended before this block
            closed = [open_peak] if math.isfinite(open_peak) else []
        else:
            found[0] = max(found[0], open_peak)
        closed += found[:-1]
        self._open_peak[j] = found[-1]
        self._last_above[j] = last
        self._close(j, closed)

    def _close(self, j: int, peaks: Sequence[float]) -> None:
        self._counts[j] += len(peaks)
        kept = self._peaks[j]
        if kept is None:
            return
        if self._counts[j] > MAX_PEAKS:
            self._peaks[j] = None
        else:
            kept.extend(peaks)

    @property
    def excursions(self) -> Excursions:
        """Everything counted so far, the open excursions closed (the log's end)."""
        counts = self._counts.copy()
        peaks = [None if p is None else list(p) for p in self._peaks]
        for j in np.flatnonzero(np.isfinite(self._open_peak)):
            counts[j] += 1
            kept = peaks[j]
            if kept is not None:
                peaks[j] = None if counts[j] > MAX_PEAKS else [*kept, float(self._open_peak[j])]
        return Excursions(
            tuple(int(c) for c in counts),
            tuple(None if p is None else tuple(sorted(p)) for p in peaks),
            round(self._usable * self.period_s * 1e9),
        )


@dataclass(frozen=True)
class TailFit:
    """The threshold of a false-alarm budget from excursions: what was fitted and its result."""

    # "pot-gpd", "pot-exponential" with too few peaks for the GPD, "bulk-exponential" (the depth
    # statistic: ``fit_bulk_tail``), or "rice-gaussian" (older files: shape 0, scale σ)
    method: str
    per_hour: float  # the budget
    level: float  # u
    peaks: int  # excursions above u
    rate_per_hour: float  # λ: excursions above u per hour of clean time
    shape: float  # ξ (0 for the exponential tail)
    scale: float  # β
    estimate: float  # x with λ·P(peak > x) = budget
    low: float  # the interval of x at CONFIDENCE
    high: float | None  # None: unbounded at that confidence
    confidence: float = CONFIDENCE
    gap_s: float = DECLUSTER_GAP_S
    # minutes of clean data after which the tail would be measured rather than assumed (None:
    # it is measured, or the method does not assume one)
    firm_after_minutes: float | None = None


def return_level(u: float, shape: float, scale: float, ratio: float) -> float:
    """x with P(peak > x | peak > u) = 1/ratio for the GPD(ξ, β) of excesses over u."""
    if ratio <= 1.0:
        return u
    if abs(shape) < 1e-9:
        return u + scale * math.log(ratio)
    return u + scale / shape * math.expm1(shape * math.log(ratio))


def fit_tail(excursions: Excursions, per_hour: float, lowest: float = -math.inf) -> TailFit | None:
    """The budget's threshold from merged excursions (u at or above ``lowest``); None when no
    excursion was seen there."""
    j = excursions.level_for_fit(lowest)
    if j is None or excursions.seconds <= 0:
        return None
    u = float(LEVELS[j])
    peaks = np.asarray(excursions.peaks[j], dtype=np.float64)
    excess = peaks - u
    rate = len(peaks) / (excursions.seconds / 3600.0)
    ratio = rate / per_hour
    if len(peaks) < MIN_PEAKS:
        return _exponential(u, excess, rate, per_hour)

    shape, scale = _fit_gpd(excess)
    x = return_level(u, shape, scale, ratio)
    low, high = _profile_interval(excess, u, ratio, shape, scale, x)
    return TailFit("pot-gpd", per_hour, u, len(peaks), rate, shape, scale, x, low, high)


def fit_bulk_tail(
    excursions: Excursions, per_hour: float, mu: float, sigma: float, noise_median: float
) -> TailFit | None:
    """The budget's threshold for the depth statistic from its median ``mu`` and robust
    ``sigma``: the rate λ(u) of excursions above u ≈ μ + 2σ (the grid level at or below it),
    and above u an exponential tail of scale β = (s₀ + s₁·max(μ − μ₀, 0))·σ
    (``BULK_TAIL_SCALE``; μ₀ = ``noise_median``, the score's median were the residual its noise
    alone; μ − μ₀ is held at ``MISFIT_STUDIED``, the most the study saw), so
    x = u + β·ln(λ(u)/budget). The interval carries the exact Poisson interval of
    the count at u through the same formula (the tail's scale is assumed, not measured: the
    interval does not cover it). With no excursion above u the rate is taken at the upper end
    of that interval: a bounded, cautious threshold, never none.

    Once the data hold ``TARGET_PEAKS`` excursions above μ + 3σ, the tail is measured there
    (``fit_tail``: peaks over threshold, a generalised Pareto fit) and that threshold is used;
    until then ``firm_after_minutes`` says how much clean data would hold them at the rate the
    assumed tail gives. None when there is no clean time or no spread."""
    from scipy import stats

    hours = excursions.seconds / 3600.0
    if not sigma > 0 or not hours > 0:
        return None
    firm = fit_tail(excursions, per_hour, lowest=mu + FIRM_LEVEL_SIGMA * sigma)
    if firm is not None and firm.peaks >= TARGET_PEAKS:
        return firm
    j = max(int(np.searchsorted(LEVELS, mu + BULK_LEVEL_SIGMA * sigma, side="right")) - 1, 0)
    u, count = float(LEVELS[j]), excursions.counts[j]
    noise, misfit = BULK_TAIL_SCALE
    excess = min(max(mu - noise_median, 0.0), MISFIT_STUDIED)
    beta = (noise + misfit * excess) * sigma
    alpha = 1.0 - CONFIDENCE
    low = float(stats.chi2.ppf(alpha / 2, 2 * count)) / 2 / hours if count else 0.0
    high = float(stats.chi2.ppf(1 - alpha / 2, 2 * count + 2)) / 2 / hours
    rate = count / hours if count else high

    def level(r: float) -> float:
        return u + beta * math.log(max(r / per_hour, 1.0))

    firm_rate = rate * math.exp(-(mu + FIRM_LEVEL_SIGMA * sigma - u) / beta)
    return TailFit(
        "bulk-exponential",
        per_hour,
        u,
        count,
        rate,
        0.0,
        beta,
        level(rate),
        level(low),
        level(high),
        firm_after_minutes=60.0 * TARGET_PEAKS / firm_rate,
    )


def _fit_gpd(excess: FloatArray) -> tuple[float, float]:
    """Maximum-likelihood (ξ, β) with ξ held within ``SHAPES`` (above 1 the tail would have no
    mean): at a bound, β is fitted with ξ fixed there."""
    from scipy import stats

    shape, _, scale = stats.genpareto.fit(excess, floc=0.0)
    if not SHAPES[0] <= shape <= SHAPES[1]:
        bound = min(max(float(shape), SHAPES[0]), SHAPES[1])
        shape, _, scale = stats.genpareto.fit(excess, f0=bound, floc=0.0)
    return float(shape), max(float(scale), np.finfo(float).tiny)  # equal peaks: β → 0


def _exponential(u: float, excess: FloatArray, rate: float, per_hour: float) -> TailFit:
    """ξ = 0: β̂ = mean excess, and 2nβ̂/β ~ χ²(2n) gives its exact interval."""
    from scipy import stats

    n = len(excess)
    scale = max(float(excess.mean()), np.finfo(float).tiny)
    ratio = rate / per_hour
    alpha = 1.0 - CONFIDENCE
    lo_scale = 2 * n * scale / float(stats.chi2.ppf(1 - alpha / 2, 2 * n))
    hi_scale = 2 * n * scale / float(stats.chi2.ppf(alpha / 2, 2 * n))
    return TailFit(
        "pot-exponential",
        per_hour,
        u,
        n,
        rate,
        0.0,
        scale,
        return_level(u, 0.0, scale, ratio),
        return_level(u, 0.0, lo_scale, ratio),
        return_level(u, 0.0, hi_scale, ratio),
    )


def _gpd_loglik(excess: FloatArray, shape: float, scale: float) -> float:
    if scale <= 0:
        return -math.inf
    z = 1.0 + shape * excess / scale
    if np.any(z <= 0):
        return -math.inf
    if abs(shape) < 1e-9:
        return float(-len(excess) * math.log(scale) - excess.sum() / scale)
    return float(-len(excess) * math.log(scale) - (1.0 + 1.0 / shape) * np.log(z).sum())


def _profile(excess: FloatArray, u: float, ratio: float, x: float) -> float:
    """max over ξ of the log-likelihood with the return level fixed at x (β follows from x)."""
    from scipy.optimize import minimize_scalar

    z = x - u
    if z <= 0 or ratio <= 1.0:
        return -math.inf
    log_ratio = math.log(ratio)

    def minus(shape: float) -> float:
        grow = math.expm1(shape * log_ratio) / shape if abs(shape) > 1e-9 else log_ratio
        value = -_gpd_loglik(excess, shape, z / grow)
        return value if math.isfinite(value) else 1e300

    best = minimize_scalar(minus, bounds=SHAPES, method="bounded", options={"xatol": 1e-6})
    return -float(best.fun)


def _profile_interval(
    excess: FloatArray, u: float, ratio: float, shape: float, scale: float, x: float
) -> tuple[float, float | None]:
    """The profile-likelihood interval of the return level x at ``CONFIDENCE`` (Coles §4.3.3)."""
    from scipy import stats
    from scipy.optimize import brentq

    if ratio <= 1.0 or x <= u:
        return x, x
    top = max(_gpd_loglik(excess, shape, scale), _profile(excess, u, ratio, x))
    cut = top - 0.5 * float(stats.chi2.ppf(CONFIDENCE, 1))

    def gap(v: float) -> float:
        return _profile(excess, u, ratio, v) - cut

    z = x - u
    low_end = u + z * 1e-6
    low = brentq(gap, low_end, x, xtol=1e-9 * z) if gap(low_end) < 0 < gap(x) else low_end
    high: float | None = None
    far = x
    for _ in range(40):  # widen until the profile drops below the cut (or give up: unbounded)
        far = u + (far - u) * 2.0
        if gap(far) < 0:
            high = brentq(gap, x, far, xtol=1e-9 * z)
            break
    return float(low), None if high is None else float(high)
