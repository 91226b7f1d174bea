"""``evaluate``'s per-log work for the calibration's own model, at flat memory: each log streams
block by block down ``detect``'s chain and its ``ScoringStage`` (the scores, flags and events
``detect_streamed`` gives, the same ``EventTracker`` closing the events), and what the metrics need
is kept as it passes: per judged sample its score (float64) filed by its label (the scores of
labelled and of unlabelled samples, each sorted at the log's end: ``ScoredUnits``), 8 bytes;
per log its event counts (``EventTally``), a few numbers per labelled event.

``judge_log`` judges a test (or validation) log at a calibration's threshold (what a validation
log contributes to μ, σ and a threshold rule is ``twincd.calibration.threshold.score_log``'s, as
`threshold` computes it). It is a module-level function of picklable arguments: any executor maps
it over logs.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from twincd.detection.detect import ScoringStage
from twincd.detection.events import Event
from twincd.evaluation.metrics import EventCounts, EventTally, ScoredUnits
from twincd.io.labels import read_label_spans
from twincd.io.links import read_link_messages
from twincd.types import FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.prepare.setup import Setup

log = logging.getLogger("twincd")


class UnseenPushes:
    """The labelled pushes (spans of the label's messages, ``read_label_spans``) that no judged
    sample falls in, sample blocks pushed by log time as they come."""

    def __init__(self, spans: IntArray) -> None:
        self.spans = spans
        self.seen = np.zeros(len(spans), dtype=bool)

    def push(self, log_time_ns: IntArray) -> None:
        if not len(self.spans):
            return
        t = np.asarray(log_time_ns, dtype=np.int64)
        at = np.searchsorted(self.spans[:, 0], t, side="right") - 1
        inside = (at >= 0) & (t < self.spans[np.maximum(at, 0), 1])
        self.seen[at[inside]] = True

    @property
    def unseen(self) -> int:
        return int(np.count_nonzero(~self.seen))


@dataclass(frozen=True)
class JudgedLog:
    """What ``evaluate`` keeps of one log judged by a calibration model: the scores of its
    judged samples (every sample: its ends with their own noise) by label, and its counts."""

    source: str
    samples: int  # every sample read
    positives: int  # samples labelled as collision
    labelled: bool  # the log carries collision labels
    units: ScoredUnits = field(repr=False)  # the judged samples' scores, by label
    events: EventCounts = field(default_factory=EventCounts)
    score_s: float = 0.0  # seconds spent scoring (reading and the twin not included)

    @property
    def judged(self) -> int:
        return self.units.units


class _Column:
    """float64 values appended block by block into one array, grown in place (``realloc``) a
    step at a time: never a second copy of what it holds, at most a step unused."""

    STEP = 1 << 20

    def __init__(self) -> None:
        self._data = np.zeros(0)
        self._n = 0

    def extend(self, values: FloatArray) -> None:
        end = self._n + len(values)
        if end > len(self._data):
            self._data.resize(max(end, len(self._data) + self.STEP), refcheck=False)
        self._data[self._n : end] = values
        self._n = end

    def sorted(self) -> FloatArray:
        """The values, sorted (the column's own array, trimmed in place)."""
        self._data.resize(self._n, refcheck=False)
        self._data.sort()
        out, self._data, self._n = self._data, np.zeros(0), 0
        return out


def judge_log(
    path: str | Path,
    calibration: Calibration,
    setup: Setup,
    link_topic: str | None = None,
    method: str = "",
    isolates: bool = True,
    keep: bool = True,
) -> JudgedLog:
    """Score, flag and group one log's samples into events as ``detect_streamed`` does (the
    calibration's model and threshold), streamed; count its labelled events found, their delays
    and the false alarms (``EventTally``). ``link_topic``: where the log names the touched link
    (isolation is judged when it does, the method ``isolates`` and a robot model is known);
    ``method``: who is said to flag a log mostly; ``keep``: keep the judged samples' scores
    (False: counts only, e.g. the false alarms of validation logs)."""
    source = str(Path(path))
    setup.check_against(calibration)
    links = read_link_messages(path, link_topic, setup.strict) if link_topic else None
    spans = read_label_spans(path, setup.options.label_topic, setup.strict)
    pushes = None if spans is None else UnseenPushes(spans)
    tally = EventTally(None if links is None else links.values)
    stage = ScoringStage(calibration)
    events: list[Event] = []
    positive, negative = _Column(), _Column()  # scores of labelled and unlabelled samples
    positives = 0
    labelled = False
    score_s = 0.0
    with setup.open(path, model=stage.model, jump=stage.score.jump) as stream:
        for frame in stream:
            stage.regressor_mask = stream.regressor_mask
            stage.regressor_theta = stream.features.theta
            start = time.perf_counter()
            out, closed = stage.push(frame)
            score_s += time.perf_counter() - start
            events.extend(closed)
            if not out.n:
                continue
            truth = frame.get("labels")
            labelled |= truth is not None
            label = np.zeros(out.n, dtype=bool) if truth is None else np.asarray(truth, bool)
            positives += int(np.count_nonzero(label))
            held = None if links is None else links.held(frame["log_time_ns"])
            if pushes is not None:
                pushes.push(frame["log_time_ns"])
            tally.push(frame["stamp_ns"], label, out["flag"], held)
            if keep:
                score = np.asarray(out["score"], dtype=np.float64)
                positive.extend(score[label])
                negative.extend(score[~label])
        events.extend(stage.finish())
        robot = stream.robot
        samples = stream.samples
    stage.counts.warn(source, by=method)
    isolation = links is not None and isolates and robot is not None
    counts = tally.finish(events, isolation)
    if pushes is not None and pushes.unseen:
        counts = replace(counts, events_not_judged=pushes.unseen)
        log.warning(
            "%s: %d labelled push(es) fell where no sample was judged (a hole in the log): "
            "not judged, counted apart from the %d pushes judged",
            source,
            pushes.unseen,
            counts.events_total,
        )
    return JudgedLog(
        source=source,
        samples=samples,
        positives=positives,
        labelled=labelled,
        units=ScoredUnits(positive.sorted(), negative.sorted()),
        events=counts,
        score_s=score_s,
    )
