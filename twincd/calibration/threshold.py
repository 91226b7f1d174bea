"""The detection threshold from the score on collision-free logs: the threshold of a false-alarm
budget per hour of collision-free time extrapolated from the score's excursions
(``twincd.calibration.tail``: an exponential tail above the bulk for the depth statistic, the
default models' score; peaks over threshold and a generalised Pareto tail for other scores), or the
paper's μ + kσ (``threshold_from_parts``).

Everything a log contributes merges exactly in any order: μ and σ from mergeable sums, the
median and MAD from a fixed histogram, the excursions' peaks per level, and the clean time.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from twincd.calibration import Calibration, Threshold, clean_mask, clean_rows
from twincd.calibration.models import depth_noise_median, model_inputs
from twincd.calibration.tail import (
    MIN_PEAKS,
    MISFIT_STUDIED,
    ExcursionCounter,
    Excursions,
    fit_bulk_tail,
    fit_tail,
)
from twincd.defaults import DEFAULT_FALSE_ALARMS_PER_HOUR, DEFAULT_K_SIGMA
from twincd.errors import DataError, UsageError
from twincd.prepare.setup import PreparedLog, Setup
from twincd.signal.edges import edge_scaled
from twincd.signal.features import ModelInputs
from twincd.signal.moments import Moments
from twincd.types import BoolArray, FloatArray, IntArray

log = logging.getLogger("twincd")


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
        return Threshold(k_sigma, self.mu, self.sigma, tuple(logs), self.n)


def _weighted_median(values: FloatArray, counts: IntArray) -> float:
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(counts[order])
    at = int(np.searchsorted(cumulative, cumulative[-1] / 2.0))
    return float(values[order][at])


def check_threshold_choice(k_sigma: float | None, per_hour: float | None) -> None:
    """k or a budget (not both), each valid: checked before any work is done."""
    if k_sigma is not None and per_hour is not None:
        raise UsageError(
            "give k or a false-alarm budget, not both",
            "threshold",
            "drop one of them",
            option="sigma,false_alarms_per_hour",
        )
    check_threshold_settings(DEFAULT_K_SIGMA if k_sigma is None else k_sigma, per_hour)


def check_threshold_settings(k_sigma: float, per_hour: float | None = None) -> None:
    """A finite k ≥ 0, and a finite budget > 0 when one is given (checked before any work)."""
    if not (math.isfinite(k_sigma) and k_sigma >= 0):
        raise UsageError(
            f"k of the threshold μ + kσ must be a finite number ≥ 0, not {k_sigma}",
            "threshold",
            "give k such as 4 (the paper's)",
            option="sigma",
        )
    if per_hour is not None and not (math.isfinite(per_hour) and per_hour > 0):
        raise UsageError(
            f"the false-alarm budget must be a finite number > 0 per hour, not {per_hour}",
            "threshold",
            "give a budget such as 1 (per hour)",
            option="false_alarms_per_hour",
        )


def budget_threshold(
    excursions: Excursions,
    stats: ScoreStats,
    per_hour: float = DEFAULT_FALSE_ALARMS_PER_HOUR,
    logs: Sequence[str] = (),
    depth: bool = False,
    noise_median: float = 0.0,
) -> Threshold:
    """The threshold x of a false-alarm budget extrapolated from the score's excursions (see
    ``twincd.calibration.tail``), never below μ, as μ + kσ with its k; with it the tail fit and the
    clean time judged (the false alarms the logs give at x are ``detect``'s events: counted once x
    is known, ``twincd.detection.files.record_false_alarms``).

    ``depth``: the score is the depth statistic: μ and σ are the median and MAD, and the
    excursions' rate at μ + 2σ is carried to the budget by an exponential tail (``fit_bulk_tail``,
    whose scale grows as μ rises above ``noise_median``; measured instead once the data allow);
    else the peaks' tail (``fit_tail``), μ and σ the mean
    and standard deviation."""
    check_threshold_settings(0.0, per_hour)
    minutes = excursions.seconds / 60.0
    mean: float | None = None
    sd: float | None = None
    if depth:
        mu, sigma = stats.robust()
        estimator = "median-mad"
        mean, sd = stats.mu, stats.sigma
        tail = fit_bulk_tail(excursions, per_hour, mu, sigma, noise_median)
        if mu - noise_median > MISFIT_STUDIED:
            log.warning(
                "the clean score's median on these logs is %.3g, above the %.3g the residual's "
                "noise alone would give: the calibration fits them less well than its training "
                "logs (too little or too different training motion, another payload or effort "
                "scale?); the false-alarm budget is extrapolated",
                mu,
                noise_median,
            )
    else:
        mu, sigma = stats.mu, stats.sigma  # no collision-free samples: a clear error here
        estimator = "mean-sd"
        tail = fit_tail(excursions, per_hour)
    if tail is None:
        log.warning(
            "the score has no excursions to fit a tail to in %.3g min of collision-free "
            "data (constant, or one level throughout): the threshold is μ + %gσ instead",
            minutes,
            DEFAULT_K_SIGMA,
        )
        return Threshold(
            DEFAULT_K_SIGMA, mu, sigma, tuple(logs), stats.n, estimator=estimator, mean=mean, sd=sd
        )
    if tail.method == "pot-exponential":
        log.warning(
            "only %d score excursion(s) in %.3g min of collision-free data, fewer than the %d "
            "a tail shape needs: the threshold assumes an exponential tail, which heavy tails "
            "exceed; give more clean validation data",
            tail.peaks,
            minutes,
            MIN_PEAKS,
        )
    value = max(tail.estimate, mu)
    k_sigma = (value - mu) / sigma if sigma > 0 else 0.0
    return Threshold(
        k_sigma,
        mu,
        sigma,
        tuple(logs),
        stats.n,
        budget_per_hour=per_hour,
        judged_s=excursions.seconds,
        tail=tail,
        estimator=estimator,
        mean=mean,
        sd=sd,
    )


@dataclass(frozen=True)
class NoiseRatio:
    """Mergeable: per joint the sum of its squared residual in noise units
    (``ResidualModel.in_noise_units``) over ``n`` collision-free samples; its RMS is about 1 on
    clean data the calibration fits."""

    n: int = 0
    ss: FloatArray | None = None  # (D,)

    @classmethod
    def from_residual(cls, units: FloatArray | None, mask: BoolArray) -> NoiseRatio:
        if units is None:
            return cls()
        z = np.asarray(units, dtype=np.float64)[mask]
        return cls(len(z), (z * z).sum(axis=0))

    def __add__(self, other: NoiseRatio) -> NoiseRatio:
        if other.ss is None:
            return self
        if self.ss is None:
            return other
        return NoiseRatio(self.n + other.n, self.ss + other.ss)

    @property
    def rms(self) -> FloatArray | None:
        """(D,) each joint's residual RMS over its noise (None: nothing counted)."""
        if self.ss is None or self.n == 0:
            return None
        out: FloatArray = np.sqrt(self.ss / self.n)
        return out


@dataclass(frozen=True)
class LogScores:
    """What one validation log contributes to a threshold (the per-log step)."""

    source: str
    stats: ScoreStats
    samples: int = 0  # every sample read (labelled ones too): what progress counts
    excursions: Excursions | None = None
    noise: NoiseRatio = NoiseRatio()  # each joint's residual over the fit's noise


def score_log(path: str | Path, calibration: Calibration, setup: Setup) -> LogScores:
    """Stream one log into statistics of its calibrated score on collision-free samples, its
    excursions and each joint's residual over the noise the fit left it (``setup``: the
    calibration's way of reading logs, ``Setup.check_against``)."""
    setup.check_against(calibration)
    stats = ScoreStats()
    noise = NoiseRatio()
    model = calibration.model
    with setup.open(path, model=model) as stream:
        peaks: ExcursionCounter | None = None
        for frame in stream:
            peaks = peaks or ExcursionCounter(stream.period_s)
            inputs = ModelInputs.of(
                frame, stream.coulomb_eps, stream.regressor_mask, stream.features.theta
            )
            # a grid's frames carry the prediction, made on its nodes (twincd.prepare.chain)
            residual = model.residual(inputs, frame.get("predicted"))
            velocity = inputs.velocity
            speed = None if velocity is None else np.asarray(velocity, dtype=np.float64)
            judged = edge_scaled(residual, frame.get("edge_factor"))
            scores = model.score(judged, speed)
            usable = clean_rows(frame.get("labels"), frame.n)
            stats = stats + ScoreStats.from_scores(scores, usable)
            noise = noise + NoiseRatio.from_residual(model.in_noise_units(judged, speed), usable)
            peaks.push(scores, usable)
    excursions = None if peaks is None else peaks.excursions
    return LogScores(str(path), stats, stream.samples, excursions, noise)


# threshold logs whose residual is this many times the noise the fit left it are refused: for
# the depth statistic, a clean median above the one such a residual gives (5.45 for 6 joints,
# 5.93 for 7: above the thresholds clean data the calibration fits are given, 4.5–6.7 on the
# real arm, so half their clean samples would be collisions there); for the other scores, a
# clean mean score above MISFIT_REFUSED² times the fit's own (the fit's residual RMSE per joint)
MISFIT_REFUSED = 3.0


def misfit(stats: ScoreStats, noise: NoiseRatio, calibration: Calibration) -> str | None:
    """What makes these logs not collision-free data the calibration fits, in one clause (None:
    nothing): their clean score far above the calibration's clean level (``MISFIT_REFUSED``),
    with the joints whose residual strays furthest from the fit's noise."""
    if stats.n == 0:
        return None
    model = calibration.model
    joints = len(calibration.joint_names)
    if model.statistic == "depth":
        median = stats.robust()[0]
        clean, limit = depth_noise_median(joints), depth_noise_median(joints, MISFIT_REFUSED)
        if median <= limit:
            return None
        top = HISTOGRAM_LOW + HISTOGRAM_STEP * (HISTOGRAM_BINS - 1)
        above = " or more" if median >= top else ""  # beyond the histogram's last bin
        level = (
            f"their collision-free score has median {median:.3g}{above}, where data the "
            f"calibration fits score about {clean:.2g} (a residual at {MISFIT_REFUSED:g}× "
            f"its noise: {limit:.2g})"
        )
    else:
        scale = model.scale_ if model.scale_ is not None else model.rmse_
        if scale is None:
            return None  # files without the fit's RMSE: no clean level to compare with
        own = float(np.sum(np.square(scale))) if model.scale_ is None else float(joints)
        ratio = stats.mean / max(own, 1e-300)
        if not ratio > MISFIT_REFUSED**2:
            return None
        level = (
            f"their collision-free score's mean is {ratio:.3g}× the fit's own (more than "
            f"{MISFIT_REFUSED**2:g}×: a residual over {MISFIT_REFUSED:g}× the fit's)"
        )
    rms = noise.rms
    if rms is not None:
        order = np.argsort(-rms, kind="stable")[:3]
        level += "; the residual over the fit's noise: " + ", ".join(
            f"{calibration.joint_names[i]} {rms[i]:.3g}×" for i in order
        )
    return level


def check_fit(
    stats: ScoreStats,
    noise: NoiseRatio,
    calibration: Calibration,
    logs: Sequence[str],
    refuse: bool = True,
) -> None:
    """Refuse (``refuse``: else warn) threshold logs that are not collision-free data the
    calibration fits (``misfit``): a threshold set on them would sit far above what the
    calibration's own clean data give, and ``detect`` would be blind."""
    found = misfit(stats, noise, calibration)
    if found is None:
        return
    what = f"these logs are not collision-free data the calibration fits: {found}"
    hint = (
        "give collision-free logs of the arm at work as in the fit's logs (moving, with the "
        "same payload, effort sign and scale), or fit the calibration on logs like these"
    )
    if not refuse:
        log.warning("%s (%s) — %s", what, _logs_text(logs), hint)
        return
    raise DataError(what, _logs_text(logs), hint)


def _logs_text(logs: Sequence[str]) -> str:
    if not logs:
        return "threshold"
    return logs[0] + (f" and {len(logs) - 1} more" if len(logs) > 1 else "")


def threshold_from_parts(
    parts: Iterable[LogScores],
    calibration: Calibration,
    k_sigma: float | None = None,
    false_alarms_per_hour: float | None = None,
    refuse: bool = True,
) -> Calibration:
    """The calibration with a threshold from per-log parts merged in any order: μ + kσ (mean
    and standard deviation) when ``k_sigma`` is given; else the threshold of a false-alarm
    budget (``false_alarms_per_hour``, by default ``DEFAULT_FALSE_ALARMS_PER_HOUR``) for a model
    scored by the depth statistic (median and MAD, an exponential tail above the bulk:
    ``budget_threshold``), or when a budget is asked for; else the paper's μ + 4σ (the affine
    and unwhitened models). Logs that are not collision-free data the calibration fits
    (``check_fit``) are refused (``refuse``; else said in a warning).

    Robust μ and σ because a validation log may hold unlabelled contact: on the real arm's six
    rotations (threshold on one log, test on another) one with 23 s of it put the paper's
    μ + 4σ at z = 21 (2 of 32 pushes found there), and the peaks' own GPD tail at z = 7–18
    (120/169 found); the bulk's rate with the assumed tail does not see such contact
    (studies/choose_budget.py)."""
    parts = sorted(parts, key=lambda p: p.source)
    total = ScoreStats()
    excursions = Excursions()
    noise = NoiseRatio()
    for p in parts:
        total = total + p.stats
        noise = noise + p.noise
        if p.excursions is not None:
            excursions = excursions + p.excursions
    seen = [p.source for p in parts]
    reused = sorted(set(seen) & set(calibration.fit.logs))
    if reused:
        log.warning(
            "%d threshold log(s) were also used by fit (%s): the threshold will be optimistic; "
            "use separate validation logs",
            len(reused),
            reused[0],
        )
    check_threshold_choice(k_sigma, false_alarms_per_hour)
    check_fit(total, noise, calibration, seen, refuse)
    if k_sigma is not None:
        return replace(calibration, threshold=total.threshold(k_sigma, seen))
    depth = calibration.model.statistic == "depth"
    if false_alarms_per_hour is None and not depth:
        # the paper's model and its sum-of-squares scores: the paper's μ + 4σ
        return replace(calibration, threshold=total.threshold(DEFAULT_K_SIGMA, seen))
    budget = (
        DEFAULT_FALSE_ALARMS_PER_HOUR if false_alarms_per_hour is None else false_alarms_per_hour
    )
    clean = depth_noise_median(len(calibration.joint_names)) if depth else 0.0
    threshold = budget_threshold(excursions, total, budget, seen, depth, clean)
    return replace(calibration, threshold=threshold)


def threshold_prepared_logs(
    logs: Iterable[PreparedLog],
    calibration: Calibration,
    k_sigma: float | None = None,
    false_alarms_per_hour: float | None = None,
) -> Calibration:
    """The threshold from logs already prepared in memory (as evaluate uses), by the rules of
    ``threshold_from_parts``."""
    parts = []
    model = calibration.model
    for lg in logs:
        inputs = model_inputs(lg)
        residual = edge_scaled(model.residual(inputs), lg.edge_factor)
        scores = model.score(residual, lg.states.velocity)
        usable = clean_mask(lg)
        period = lg.period_s or float(np.median(np.diff(lg.states.stamp_ns))) * 1e-9
        peaks = ExcursionCounter(period)
        peaks.push(scores, usable)
        stats = ScoreStats.from_scores(scores, usable)
        noise = NoiseRatio.from_residual(model.in_noise_units(residual, lg.states.velocity), usable)
        parts.append(LogScores(lg.source, stats, len(lg), peaks.excursions, noise))
    # evaluate's thresholds: logs the calibration does not fit are said, and judged all the same
    return threshold_from_parts(parts, calibration, k_sigma, false_alarms_per_hour, refuse=False)


def same_rule(calibration: Calibration) -> tuple[float | None, float | None]:
    """(k_sigma, false_alarms_per_hour) that set the calibration's threshold: its budget when it
    has one, else its k (for ``threshold_*`` on other logs)."""
    th = calibration.require_threshold()
    if th.budget_per_hour is not None:
        return None, th.budget_per_hour
    return th.k_sigma, None
