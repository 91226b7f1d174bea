"""Detection on a log file, streamed block by block at flat memory: the log's frames (read,
twinned and filtered by ``twincd.pipeline``, down the chain ``twincd.chain.build_chain`` builds
for the calibration, zero-phase or causal) scored, flagged and grouped into events. Only counts
and events are kept; per-sample results go to sinks."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from twincd.detection.detect import MOSTLY_FLAGGED, DetectionSummary, ScoringStage
from twincd.detection.events import Event
from twincd.errors import DataError
from twincd.frames import Frame, FrameSink

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.pipeline import Setup

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
    with setup.open(path, model=stage.model) as stream:
        for frame in stream:
            stage.regressor_mask = stream.regressor_mask
            stage.regressor_theta = stream.features.theta
            out, closed = stage.push(frame)
            _deliver(summary, sinks, out, closed)
        _deliver(summary, sinks, Frame(), stage.finish())
        summary.joint_names = stream.joint_names
        summary.period_s = stream.period_s
    stage.counts.warn(str(path))
    return summary


@dataclass(frozen=True)
class AlarmTally:
    """One log's false alarms at a calibration's threshold and its judged clean time."""

    source: str
    false_alarms: int
    clean_s: float
    clean_samples: int = 0  # judged collision-free samples
    clean_flagged: int = 0  # of those, flagged at the threshold


@contextlib.contextmanager
def _said_already() -> Iterator[None]:
    """Warnings off: a second pass over logs whose warnings the first pass gave."""
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(level)


def tally_false_alarms(path: str | Path, calibration: Calibration, setup: Setup) -> AlarmTally:
    """``detect``'s false alarms on one log at the calibration's threshold (its events touching
    no labelled push ± 200 ms), and the log's judged collision-free time: how ``threshold``
    counts what its own logs give at the threshold it chose."""
    with _said_already():
        summary = detect_streamed(path, calibration, setup)
    return AlarmTally(
        str(path),
        summary.false_alarms,
        summary.clean_s,
        summary.clean_samples,
        summary.clean_flagged,
    )


def record_false_alarms(calibration: Calibration, tallies: Iterable[AlarmTally]) -> Calibration:
    """The calibration with its threshold's false alarms counted on ``tallies`` (its own logs)
    and their clean time; a warning when a budget's threshold gave more than the budget allows
    for that time (``twincd.detection.events.allowed_false_alarms``). A threshold that flags most of
    its own logs' collision-free samples (more than ``MOSTLY_FLAGGED``, as ``detect`` judges a
    log the calibration does not fit) is refused: those logs are not collision-free data the
    calibration fits (a score stuck at one level, σ = 0)."""
    from twincd.detection.events import allowed_false_alarms

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
    if th.budget_per_hour is not None:
        allowed = allowed_false_alarms(th.budget_per_hour, seconds / 3600.0)
        if count > allowed:
            log.warning(
                "the threshold gave %d false alarm(s) on its own %.3g min of collision-free "
                "data, more than a budget of %g per hour allows there (%d): the score's tail is "
                "heavier than assumed; give more clean validation logs, or a larger budget",
                count,
                seconds / 60.0,
                th.budget_per_hour,
                allowed,
            )
    return replace(calibration, threshold=replace(th, false_alarms=count, judged_s=seconds))


def _deliver(
    summary: DetectionSummary, sinks: Sequence[FrameSink], frame: Frame, events: list[Event]
) -> None:
    summary.add(frame, events)
    for sink in sinks:
        sink.write(frame, events)
