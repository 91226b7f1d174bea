"""Detection on a log file, streamed block by block at flat memory: the log's frames (read,
twinned and filtered by ``twincd.prepare.stream``, down the chain
``twincd.prepare.chain.build_chain`` builds for the calibration, zero-phase or causal) scored,
flagged and grouped into events. Only counts and events are kept; per-sample results go to sinks."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from twincd.detection.detect import MOSTLY_FLAGGED, DetectionSummary, ScoringStage
from twincd.detection.events import Event
from twincd.errors import DataError
from twincd.prepare.frames import Frame, FrameSink
from twincd.prepare.notices import said_already

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.calibration.threshold import LogScores
    from twincd.executors.run import Each
    from twincd.prepare.setup import Setup

log = logging.getLogger("twincd")


def detect_streamed(
    path: str | Path,
    calibration: Calibration,
    setup: Setup,
    sinks: Sequence[FrameSink] = (),
) -> DetectionSummary:
    """Detect collisions in one log streamed block by block; every frame of results also goes
    to ``sinks``. The chain and the scoring are those of ``OnlineDetector``: with a causal
    calibration, a log pushed live in any chunking gives the same scores, flags and events."""
    summary = DetectionSummary(str(path), calibration.require_threshold().value)
    # the stream reads the log the calibration's way, its columns in the calibration's joints
    setup.check_against(calibration)
    stage = ScoringStage(calibration)
    with setup.open(path, model=stage.model, jump=stage.score.jump) as stream:
        for frame in stream:
            stage.regressor_mask = stream.regressor_mask
            stage.regressor_theta = stream.features.theta
            out, closed = stage.push(frame)
            summary.period_s = stream.period_s  # known from the first block on
            _deliver(summary, sinks, out, closed)
        _deliver(summary, sinks, Frame(), stage.finish())
        summary.joint_names = stream.joint_names
        summary.period_s = stream.period_s
    stage.counts.warn(str(path))
    return summary


@dataclass(frozen=True)
class AlarmTally:
    """One log's false alarms at a calibration's threshold, their peak scores and its judged
    clean time."""

    source: str
    false_alarms: int
    clean_s: float
    clean_samples: int = 0  # judged collision-free samples
    clean_flagged: int = 0  # of those, flagged at the threshold
    peaks: tuple[float, ...] = ()  # each false alarm's peak score


def tally_false_alarms(path: str | Path, calibration: Calibration, setup: Setup) -> AlarmTally:
    """``detect``'s false alarms on one log at the calibration's threshold (its events touching
    no labelled push ± 200 ms), and the log's judged collision-free time: how ``threshold``
    counts what its own logs give at the threshold it chose."""
    from twincd.detection.events import false_alarm_events

    with said_already():
        summary = detect_streamed(path, calibration, setup)
    alarms = false_alarm_events(summary.events, summary.labels.finish())
    return AlarmTally(
        str(path),
        len(alarms),
        summary.clean_s,
        summary.clean_samples,
        summary.clean_flagged,
        tuple(e.peak_score for e in alarms),
    )


def record_false_alarms(calibration: Calibration, tallies: Iterable[AlarmTally]) -> Calibration:
    """The calibration with its threshold's false alarms counted on ``tallies`` (its own logs)
    and their clean time. A budget's threshold is held to its own clean data (``keep_budget``).
    A threshold that flags most of its own logs' collision-free samples (more than
    ``MOSTLY_FLAGGED``, as ``detect`` judges a log the calibration does not fit) is refused:
    those logs are not collision-free data the calibration fits (a score stuck at one level,
    σ = 0)."""
    tallies = sorted(tallies, key=lambda t: t.source)
    th = calibration.require_threshold()
    count = sum(t.false_alarms for t in tallies)
    seconds = sum(t.clean_s for t in tallies)
    clean = sum(t.clean_samples for t in tallies)
    flagged = sum(t.clean_flagged for t in tallies)
    if clean and flagged > MOSTLY_FLAGGED * clean:
        raise DataError(
            f"these logs are not collision-free data the calibration fits: the threshold "
            f"{th.value:.4g} set on them flags {100 * flagged / clean:.0f} % of their "
            "collision-free samples (their score sits at one level: μ "
            f"{th.mu:.4g}, σ {th.sigma:.3g})",
            tallies[0].source + (f" and {len(tallies) - 1} more" if len(tallies) > 1 else ""),
            "give collision-free logs of the arm at work as in the fit's logs (moving, with the "
            "same payload, effort sign and scale), or fit the calibration on logs like these",
        )
    recorded = replace(calibration, threshold=replace(th, false_alarms=count, judged_s=seconds))
    if th.budget_per_hour is None:
        return recorded
    peaks = [p for t in tallies for p in t.peaks]
    return keep_budget(recorded, peaks)


def threshold_logs(
    parts: Sequence[LogScores],
    calibration: Calibration,
    setup: Setup,
    each: Each,
    k_sigma: float | None = None,
    false_alarms_per_hour: float | None = None,
    refuse: bool = True,
) -> Calibration:
    """What ``threshold`` makes of its logs' scores (``parts``: ``score_log`` of each): the
    threshold by its rule (``threshold_from_parts``), then, in a second pass over the same logs
    (``each`` maps ``tally_false_alarms`` over them: the events need the threshold), the false
    alarms it gives there, a budget's held to its own clean data (``record_false_alarms``)."""
    from twincd.calibration.threshold import threshold_from_parts
    from twincd.executors.local import Bound

    cal = threshold_from_parts(parts, calibration, k_sigma, false_alarms_per_hour, refuse)
    counting: Bound[Path, AlarmTally] = Bound(tally_false_alarms, cal, setup)
    tallies = each(counting, [Path(p.source) for p in parts], "counting")
    return record_false_alarms(cal, tallies)


def keep_budget(calibration: Calibration, peaks: Sequence[float]) -> Calibration:
    """A budget's threshold, raised until its own clean data pass it no more often than the
    budget allows there (the Poisson 95 % quantile of budget × hours:
    ``twincd.detection.events.allowed_false_alarms``), and said: the validation logs' false
    alarms (``peaks``: each one's peak score, counted in the threshold's ``false_alarms``) and
    the excursions of the fit's own logs, each scored by a model fitted without it
    (``FitInfo.clean``, every band carried onto the score's scale), over their clean time
    together. The tail a budget is extrapolated by is assumed; what the data show is not."""
    from twincd.detection.events import allowed_false_alarms

    th = calibration.require_threshold()
    assert th.budget_per_hour is not None and th.judged_s is not None
    fitted = _fit_peaks(calibration)
    hours = (th.judged_s + sum(b.excursions.seconds for b in calibration.fit.clean[:1])) / 3600
    allowed = allowed_false_alarms(th.budget_per_hour, hours)
    every = sorted([*peaks, *fitted], reverse=True)

    def count(x: float) -> int:
        return sum(p >= x for p in every)

    value = th.value
    passed = count(value)
    if passed <= allowed:
        return calibration
    raised = float(np.nextafter(every[allowed], np.inf))  # above the (allowed + 1)-th peak
    log.warning(
        "the threshold %.4g was passed %d time(s) by its own %.3g min of collision-free data "
        "(validation logs%s), more than a budget of %g per hour allows there (%d): raised to "
        "%.4g, the lowest they pass at most that often; the score's tail is heavier than "
        "assumed: more clean data, or a larger budget, would set it lower",
        value,
        passed,
        hours * 60.0,
        " and the fit's own, cross-fitted" if fitted else "",
        th.budget_per_hour,
        allowed,
        raised,
    )
    k_sigma = (raised - th.mu) / th.sigma if th.sigma > 0 else th.k_sigma
    alarms = sum(p >= raised for p in peaks)
    return replace(calibration, threshold=replace(th, k_sigma=k_sigma, false_alarms=alarms))


def _fit_peaks(calibration: Calibration) -> list[float]:
    """The peaks, on the score's scale, of the fit's own clean excursions that reach the
    threshold (each band's own, ``FitInfo.clean``, carried: ``Score.carried``), from the
    highest level at or below the threshold's that kept its peaks."""
    from twincd.calibration.tail import LEVELS

    th, score = calibration.require_threshold(), calibration.score
    out: list[float] = []
    for band, clean in enumerate(calibration.fit.clean[: score.bands]):
        own = score.band_level(band, th.value)
        peaks = clean.excursions.peaks
        kept = [j for j, p in enumerate(peaks) if p is not None and LEVELS[j] <= own]
        if kept:
            carried = [score.carried(band, p) for p in peaks[max(kept)] or ()]
            out += [p for p in carried if p >= th.value]
    return out


def _deliver(
    summary: DetectionSummary, sinks: Sequence[FrameSink], frame: Frame, events: list[Event]
) -> None:
    summary.add(frame, events)
    for sink in sinks:
        sink.write(frame, events)
