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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from twincd.calibration import Calibration, Threshold, clean_mask, clean_rows
from twincd.calibration.clean import (
    HISTOGRAM_BINS,
    HISTOGRAM_LOW,
    HISTOGRAM_STEP,
    BandStats,
    LabelMargin,
)
from twincd.calibration.clean import ScoreStats as ScoreStats
from twincd.calibration.models import depth_noise_median, model_inputs
from twincd.calibration.score import BandLevel
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
from twincd.prepare.frames import Derived, Frame
from twincd.prepare.prepared import PreparedLog
from twincd.prepare.setup import Setup
from twincd.signal.edges import edge_scaled
from twincd.types import BoolArray, FloatArray, IntArray

log = logging.getLogger("twincd")


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
    """What one validation log contributes to a threshold (the per-log step): each band's score
    on its collision-free samples (``BandStats``: the slow band's first)."""

    source: str
    bands: tuple[BandStats, ...]
    samples: int = 0  # every sample read (labelled ones too): what progress counts
    noise: NoiseRatio = NoiseRatio()  # each joint's residual over the fit's noise
    # the score itself (the bands combined as the calibration combines them now): what μ + iσ
    # means in evaluate's metrics
    combined: ScoreStats = field(default_factory=ScoreStats)

    @property
    def stats(self) -> ScoreStats:
        """The slow band's (the calibration model's own) score statistics."""
        return self.bands[0].stats

    @property
    def excursions(self) -> Excursions:
        return self.bands[0].excursions


class BandCounter:
    """Each band's ``BandStats`` of scored frames, block by block: collision-free samples only,
    and none within ``LABEL_MARGIN_S`` of a labelled one (``LabelMargin``; a sample waits for the
    margin after it)."""

    def __init__(self, period_s: float, bands: int) -> None:
        self.period_s = period_s
        self.margin = Derived(LabelMargin(period_s), "labels", "near_label")
        self.counters = [ExcursionCounter(period_s) for _ in range(bands)]
        self.stats = [ScoreStats() for _ in range(bands)]
        self.combined = ScoreStats()

    def push(
        self, stamp_ns: IntArray, scores: Sequence[FloatArray], combined: FloatArray, labels: Any
    ) -> None:
        n = len(stamp_ns)
        columns = {f"band{i}": s for i, s in enumerate(scores)} | {"combined": combined}
        lab = np.zeros(n) if labels is None else np.asarray(labels, dtype=np.float64)
        self._count(self.margin.push(Frame({"stamp_ns": stamp_ns, "labels": lab, **columns})))

    def finish(self) -> tuple[BandStats, ...]:
        self._count(self.margin.finish())
        return tuple(
            BandStats(st, c.excursions) for st, c in zip(self.stats, self.counters, strict=True)
        )

    def _count(self, frame: Frame) -> None:
        if not frame.n:
            return
        usable = np.asarray(frame["near_label"], dtype=np.float64).reshape(-1) == 0
        self.combined = self.combined + ScoreStats.from_scores(frame["combined"], usable)
        for i, counter in enumerate(self.counters):
            scores = frame[f"band{i}"]
            self.stats[i] = self.stats[i] + ScoreStats.from_scores(scores, usable)
            counter.push(scores, usable)


def score_log(path: str | Path, calibration: Calibration, setup: Setup) -> LogScores:
    """Stream one log into each band's statistics of its score on collision-free samples and
    their excursions (``BandCounter``), and each joint's residual over the noise the fit left it
    (``setup``: the calibration's way of reading logs, ``Setup.check_against``)."""
    setup.check_against(calibration)
    noise = NoiseRatio()
    model, score = calibration.model, calibration.score
    with setup.open(path, model=model, jump=score.jump) as stream:
        counter: BandCounter | None = None
        for frame in stream:
            counter = counter or BandCounter(stream.period_s, score.bands)
            velocity = np.asarray(frame["velocity"], dtype=np.float64)
            residual = frame["residual"]
            bands, _ = score.band_scores(
                model,
                residual,
                velocity,
                frame.get("residual_fast"),
                frame.get("edge_factor"),
                frame.get("fast_off"),
            )
            combined = score.combine(bands)
            counter.push(frame["stamp_ns"], bands, combined, frame.get("labels"))
            judged = edge_scaled(residual, frame.get("edge_factor"))
            usable = clean_rows(frame.get("labels"), frame.n)
            noise = noise + NoiseRatio.from_residual(model.in_noise_units(judged, velocity), usable)
        bands_stats = (BandStats(),) * score.bands if counter is None else counter.finish()
        whole = ScoreStats() if counter is None else counter.combined
    return LogScores(str(path), bands_stats, stream.samples, noise, whole)


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
    and standard deviation) of these logs when ``k_sigma`` is given (the paper's); else the
    threshold of a false-alarm budget (``false_alarms_per_hour``, by default
    ``DEFAULT_FALSE_ALARMS_PER_HOUR``) for a model scored by the depth statistic (median and
    MAD, an exponential tail above the bulk: ``budget_threshold``), or when a budget is asked
    for; else the paper's μ + 4σ (the affine and unwhitened models). A budget is set on every
    clean sample there is: these logs' and the fit's own, each scored by a model fitted without
    it (``FitInfo.clean``; files fitted before hold none: these logs alone, said once). A score
    of two bands gives each band its share of the budget, and of μ + kσ its own μ and σ
    (``twincd.calibration.score``: ``Score.levels``). Logs that are not collision-free data the
    calibration fits (``check_fit``) are refused (``refuse``; else said in a warning).

    Robust μ and σ because a validation log may hold unlabelled contact: on the real arm's six
    rotations (threshold on one log, test on another) one with 23 s of it put the paper's
    μ + 4σ at z = 21 (2 of 32 pushes found there), and the peaks' own GPD tail at z = 7–18
    (120/169 found); the bulk's rate with the assumed tail does not see such contact
    (studies/choose_budget.py)."""
    parts = sorted(parts, key=lambda p: p.source)
    score = calibration.score
    bands = [BandStats() for _ in range(score.bands)]
    noise = NoiseRatio()
    for p in parts:
        if len(p.bands) != score.bands:
            raise DataError(
                f"{len(p.bands)} band(s) scored for a calibration of {score.bands}",
                p.source,
                "score the logs with this calibration",
            )
        bands = [mine + theirs for mine, theirs in zip(bands, p.bands, strict=True)]
        noise = noise + p.noise
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
    check_fit(bands[0].stats, noise, calibration, seen, refuse)
    depth = calibration.model.statistic == "depth"
    if k_sigma is None and false_alarms_per_hour is None and not depth:
        k_sigma = DEFAULT_K_SIGMA  # the paper's model and its sum-of-squares scores: μ + 4σ
    if k_sigma is not None:
        return _with_levels(calibration, [b.stats.threshold(k_sigma, seen) for b in bands])
    budget = (
        DEFAULT_FALSE_ALARMS_PER_HOUR if false_alarms_per_hour is None else false_alarms_per_hour
    )
    fitted = calibration.fit.clean
    if len(fitted) == len(bands):
        bands = [mine + theirs for mine, theirs in zip(bands, fitted, strict=True)]
    elif depth:  # a fit cross-fits the models scored by depth (twincd.calibration.crossfit)
        log.warning(
            "the calibration holds no scores of its fit's own logs (written by an earlier "
            "twincd, or fitted without them): the threshold comes from these validation logs "
            "alone; re-fit it for a threshold from all the clean data there is"
        )
    clean = depth_noise_median(len(calibration.joint_names)) if depth else 0.0
    share = budget / len(bands)
    per_band = [budget_threshold(b.excursions, b.stats, share, seen, depth, clean) for b in bands]
    per_band[0] = replace(per_band[0], budget_per_hour=budget)
    return _with_levels(calibration, per_band)


def _with_levels(calibration: Calibration, per_band: Sequence[Threshold]) -> Calibration:
    """The calibration judging at the slow band's threshold, and with several bands each
    band's level (its median or mean, and its own threshold: ``Score.levels``)."""
    score = calibration.score
    if len(per_band) > 1:
        levels = tuple(BandLevel(th.mu, th.value) for th in per_band)
        score = replace(score, levels=levels)
    return replace(calibration, threshold=per_band[0], score=score)


def threshold_prepared_logs(
    logs: Iterable[PreparedLog],
    calibration: Calibration,
    k_sigma: float | None = None,
    false_alarms_per_hour: float | None = None,
) -> Calibration:
    """The threshold from logs already prepared in memory (a fit's filtered inputs, or prepared
    for the calibration's model), by the rules of ``threshold_from_parts``."""
    parts = []
    model, score = calibration.model, calibration.score
    for lg in logs:
        velocity = lg.states.velocity
        residual = lg.residual if lg.residual is not None else model.residual(model_inputs(lg))
        bands, _ = score.band_scores(
            model, residual, velocity, lg.residual_fast, lg.edge_factor, lg.fast_off
        )
        period = lg.period_s or float(np.median(np.diff(lg.states.stamp_ns))) * 1e-9
        counter = BandCounter(period, score.bands)
        counter.push(lg.states.stamp_ns, bands, score.combine(bands), lg.labels)
        judged = edge_scaled(residual, lg.edge_factor)
        noise = NoiseRatio.from_residual(model.in_noise_units(judged, velocity), clean_mask(lg))
        stats = counter.finish()
        parts.append(LogScores(lg.source, stats, len(lg), noise, counter.combined))
    # evaluate's thresholds: logs the calibration does not fit are said, and judged all the same
    return threshold_from_parts(parts, calibration, k_sigma, false_alarms_per_hour, refuse=False)


def same_rule(calibration: Calibration) -> tuple[float | None, float | None]:
    """(k_sigma, false_alarms_per_hour) that set the calibration's threshold: its budget when it
    has one, else its k (for ``threshold_*`` on other logs)."""
    th = calibration.require_threshold()
    if th.budget_per_hour is not None:
        return None, th.budget_per_hour
    return th.k_sigma, None
